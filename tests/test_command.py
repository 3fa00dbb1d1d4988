"""The milling-twin command: every subcommand's help, the exit-code table, --set, --version, info, lobes,
FMI call logging; and the Python API it is built on."""
from __future__ import annotations

import importlib
import logging
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO_ROOT
from milling_twin import __version__, cli
from milling_twin.cli import COMMANDS, EXIT_CODES, Group, UsageError, main, parse_override


def _all_subcommands() -> list[tuple[list[str], cli.Subcommand]]:
    out = []
    for command in COMMANDS:
        if isinstance(command, Group):
            out += [([command.name, s.name], s) for s in command.subcommands]
        else:
            out.append(([command.name], command))
    return out


SUBCOMMANDS = _all_subcommands()


@pytest.mark.parametrize("words", [w for w, _ in SUBCOMMANDS] + [[], ["align"], ["validate"], ["train"]],
                         ids=lambda w: " ".join(w) or "top")
def test_every_subcommand_has_help(words: list[str], capsys) -> None:
    with pytest.raises(SystemExit) as info:
        main([*words, "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert out.startswith(f"usage: milling-twin {' '.join(words)}".rstrip()), out[:200]
    if not words:
        assert "exit codes (every subcommand)" in out and "130" in out


def test_every_handler_exists() -> None:
    """Each subcommand's handler imports and is callable. In a process of its own: the force net's handlers
    import torch, whose libraries would stay loaded in pytest's process and slow every later dlopen (the
    loading-time test of test_fmu_loading.py measures those)."""
    handlers = [sub.handler for _, sub in SUBCOMMANDS]
    code = ("import importlib, importlib.util, sys\n"
            "for spec in sys.argv[1:]:\n"
            "    module, _, function = spec.partition(':')\n"
            "    if module.startswith('milling_twin.training.force_net') and importlib.util.find_spec('torch') is None:\n"
            "        print('skipped (no torch):', spec)\n"
            "        continue\n"
            "    assert callable(getattr(importlib.import_module(module), function)), spec\n"
            "print('ok')\n")
    proc = subprocess.run([sys.executable, "-c", code, *handlers], capture_output=True, text=True, cwd=REPO_ROOT,
                          timeout=300)
    assert proc.returncode == 0 and proc.stdout.strip().endswith("ok"), proc.stderr[-2000:]
    assert len(handlers) == 18


def test_the_exit_code_table_names_real_exceptions() -> None:
    for entry in EXIT_CODES:
        cls = getattr(importlib.import_module(entry.module), entry.name)
        assert isinstance(cls, type) and issubclass(cls, BaseException), entry
        assert entry.code in (1, 2, 130) and entry.meaning
    # subclasses stand before the classes they specialise, or they would never match
    classes = [getattr(importlib.import_module(e.module), e.name) for e in EXIT_CODES]
    for i, a in enumerate(classes):
        for b in classes[:i]:
            assert not issubclass(a, b) or a is b, f"{a.__name__} is shadowed by {b.__name__}"


def test_help_and_version_from_a_fresh_process() -> None:
    for argv in ([sys.executable, "-m", "milling_twin", "--version"],
                 [str(Path(sys.executable).parent / "milling-twin"), "--version"]):
        proc = subprocess.run(argv, capture_output=True, text=True, cwd=REPO_ROOT, timeout=60)
        assert proc.returncode == 0 and proc.stdout.strip() == f"milling-twin {__version__}", proc


def test_help_does_not_load_the_heavy_modules() -> None:
    code = ("import sys\nfrom milling_twin.cli import main\ntry:\n    main(['run', '--help'])\nexcept SystemExit:\n"
            "    pass\nprint(sorted(m for m in ('casadi', 'matplotlib', 'torch', 'pandas') if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=REPO_ROOT, timeout=60)
    assert proc.returncode == 0 and proc.stdout.strip().splitlines()[-1] == "[]", proc


@pytest.mark.parametrize("text, expected", [
    ("power.P_idle=250", ("power.P_idle", 250.0)),
    ("power.P_idle=0.25kW", ("power.P_idle", {"value": 0.25, "unit": "kW"})),
    ("power.P_idle = 0.25 kW", ("power.P_idle", {"value": 0.25, "unit": "kW"})),
    ("vibration.stiffness_x1=1.3e6 N/m", ("vibration.stiffness_x1", {"value": 1.3e6, "unit": "N/m"})),
    ("mrr.cutting=true", ("mrr.cutting", True)),
    ("interp.program=part.nc", ("interp.program", "part.nc")),
    ("force.Ktc=-5", ("force.Ktc", -5.0)),
])
def test_set_overrides_parse(text: str, expected: tuple) -> None:
    assert parse_override(text) == expected


def test_a_whole_number_set_stays_an_integer(make_case, fmu_dir, tmp_path) -> None:
    """--set force.n_flutes=3 sets an Int32 parameter (a float 3.0 was refused: 'give a whole number'), and a whole
    number still sets a Real one."""
    key, value = parse_override("force.n_flutes=3")
    assert (key, value, type(value)) == ("force.n_flutes", 3, int)
    assert main(["run", str(make_case()), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path), "--no-progress",
                 "--set", "power.P_standby=600"]) == 0


@pytest.mark.parametrize("text", ["P_idle=3", "power.P_idle", "=3", "power.=3", "power.c1=nan"])
def test_bad_set_overrides_are_usage_errors(text: str) -> None:
    with pytest.raises(UsageError, match="--set"):
        parse_override(text)


def test_run_with_overrides_and_a_bad_one(make_case, fmu_dir, tmp_path, capsys) -> None:
    case = str(make_case())
    base = ["run", case, "--fmu-dir", str(fmu_dir), "--out", str(tmp_path), "--no-progress"]
    assert main(base) == 0
    plain = np.asarray(__import__("milling_twin").load_results(tmp_path / "case")["power.P_total"])
    assert main([*base, "--set", "power.P_standby=0.6kW"]) == 0
    changed = np.asarray(__import__("milling_twin").load_results(tmp_path / "case")["power.P_total"])
    assert changed - plain == pytest.approx(np.full(len(plain), 600.0 - 100.0))  # the case's P_standby is 100 W
    capsys.readouterr()
    assert main([*base, "--set", "power.P_idle=5mm"]) == 2
    assert "unit 'mm' does not fit 'P_idle'" in capsys.readouterr().err
    assert main([*base, "--set", "power.c1"]) == 2
    assert "expected INSTANCE.VARIABLE=VALUE[UNIT]" in capsys.readouterr().err


def test_fmi_logging_logs_every_call_and_runs_the_python_loop(make_case, fmu_dir, tmp_path, caplog, capsys) -> None:
    with caplog.at_level(logging.INFO, logger="milling_twin.fmi"):
        assert main(["run", str(make_case()), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path), "--no-progress",
                     "--fmi-logging"]) == 0
    calls = [r.getMessage() for r in caplog.records if r.name == "milling_twin.fmi"]
    assert any(c.startswith("fmi3InstantiateCoSimulation(instanceName=\"power\"") for c in calls), calls[:3]
    assert sum(c.startswith("fmi3DoStep(") for c in calls) >= 4
    assert "python path (requested)" in capsys.readouterr().out
    assert main(["run", str(make_case()), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path), "--no-progress",
                 "--fmi-logging", "--path", "fast"]) == 2


def test_info_lists_variables_with_units_and_ranges(fmu_dir, capsys) -> None:
    assert main(["info", "SpindlePower", "--fmu-dir", str(fmu_dir)]) == 0
    out = capsys.readouterr().out
    assert out.startswith("SpindlePower (FMI 3.0 co-simulation)")
    line = next(l for l in out.splitlines() if l.strip().startswith("P_idle "))
    assert "W (kW)" in line and "200.0 (0.2)" in line and "[0, 100] kW" in line
    assert main(["info", str(fmu_dir / "SpindlePower_fmi2.fmu")]) == 0
    assert "FMI 2.0" in capsys.readouterr().out
    assert main(["info", "Nope", "--fmu-dir", str(fmu_dir)]) == 2
    assert "no such FMU file; FMUs in" in capsys.readouterr().err
    assert main(["info", str(REPO_ROOT / "README.md")]) == 2
    assert "README.md: cannot read the model description (BadZipFile: File is not a zip file)" in capsys.readouterr().err


def test_lobes_plot_csv_and_pockets(fmu_dir, tmp_path, capsys) -> None:
    from milling_twin.models.stability import Mode, stability_lobes

    out, csv = tmp_path / "lobes.png", tmp_path / "lobes.csv"
    assert main(["lobes", str(REPO_ROOT / "scenarios" / "chatter.toml"), "--fmu-dir", str(fmu_dir), "--speeds", "5000",
                 "30000", "--points", "400", "--out", str(out), "--csv", str(csv)]) == 0
    assert out.stat().st_size > 10_000
    speed, depth = np.loadtxt(csv, delimiter=",", skiprows=1, unpack=True)
    assert len(speed) == 400 and speed[0] == 5000 and speed[-1] == 30000
    # the same limit as the model's lobes for the scenario's values (922 Hz, 1.1 %, 1.34e6 N/m, slotting, 2 flutes)
    mode = (Mode(922.0, 0.011, 1.34e6),)
    from milling_twin.models import MODELS
    from milling_twin.orchestrator.scenario import load_scenario
    force = {v.name: v.start for v in MODELS["CuttingForce"].variables}
    force.update(load_scenario(REPO_ROOT / "scenarios" / "chatter.toml", fmu_dir).instance("force").parameters)
    expected = stability_lobes(mode, mode, force["Ktc"], force["Krc"], 2, lobes=60).limit(speed) * 1e3
    assert depth == pytest.approx(expected, rel=1e-4)
    assert "pocket at" in capsys.readouterr().out
    assert main(["lobes", str(REPO_ROOT / "scenarios" / "umich_power.toml"), "--fmu-dir", str(fmu_dir),
                 "--out", str(out)]) == 2
    assert "the lobes need a CuttingForce instance named 'force'" in capsys.readouterr().err


def test_align_method_choices_are_the_aligners() -> None:
    from milling_twin.orchestrator.align.temporal import METHODS

    parser = cli.build_parser()
    temporal = parser._subparsers._group_actions[0].choices["align"]._subparsers._group_actions[0].choices["temporal"]
    method = next(a for a in temporal._actions if a.dest == "method")
    assert sorted(method.choices) == sorted(METHODS)


def test_simulate_in_memory_and_to_a_folder(make_case, fmu_dir, tmp_path) -> None:
    import milling_twin as mt

    results = mt.simulate(make_case(), fmu_dir=fmu_dir, overrides={"power.P_standby": {"value": 0.6, "unit": "kW"}})
    assert results.status == "completed" and results.run_dir is None
    frame = results.frame
    assert list(frame.columns[:2]) == ["time", "power.P_total"] and len(frame) == 5
    assert frame.attrs["units"]["power.P_total"] == "W" and frame.attrs["display_units"]["power.P_total"] == "kW"
    assert results.report is not None and results.report.comparisons[0].simulated == "power.P_total"
    on_disk = mt.simulate(make_case(), fmu_dir=fmu_dir, out=tmp_path / "runs")
    assert on_disk.run_dir == tmp_path / "runs" / "case" and (on_disk.run_dir / "run.json").is_file()
    loaded = mt.load_results(on_disk.run_dir)
    assert loaded.attrs["units"] == frame.attrs["units"]
    assert float(frame["power.P_total"].iloc[0] - loaded["power.P_total"].iloc[0]) == pytest.approx(500.0)


def test_the_docs_give_the_exit_code_table_as_the_code_has_it() -> None:
    from milling_twin.cli import exit_code_table

    assert exit_code_table() in (REPO_ROOT / "docs" / "orchestrator.md").read_text(), \
        "docs/orchestrator.md: paste milling_twin.cli.exit_code_table() under 'Exit codes'"


@pytest.mark.parametrize("words, message", [
    (["reconstruct", "README.md", "-o", "{tmp}/x.nc"], "README.md: not a readable CSV file"),
    (["reconstruct", "scenarios/calibration/data/impulse_hammer.csv", "-o", "{tmp}/x.nc"],
     "impulse_hammer.csv: no column 'M1_sequence_number': a UMich recording (CSV) is expected"),
    (["validate", "forcenet-figure", "--runs", "{tmp}"], "missing: run `milling-twin validate slot-milling"),
    (["lobes", "{tmp}/none.toml"], "none.toml: scenario file not found"),
    (["align", "temporal", "--recorded", "{tmp}/none.csv", "--columns", "a,b,c", "--sample-period", "0.1",
      "--simulated", "{tmp}/s.csv", "--sim-columns", "a,b,c", "--out", "{tmp}/m.csv"], "none.csv: file not found"),
])
def test_bad_input_is_one_line_and_exit_2(words: list[str], message: str, tmp_path: Path, capsys,
                                          monkeypatch) -> None:
    monkeypatch.chdir(REPO_ROOT)
    assert main([w.format(tmp=tmp_path) for w in words]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and message in err and "Traceback" not in err, err
