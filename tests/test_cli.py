"""The command line: summary, report, clean errors and exit codes, Ctrl-C."""
from __future__ import annotations

import json
import math
import signal
import subprocess
import sys

import numpy as np
import pytest

from conftest import REPO_ROOT
from milling_twin.cli import main
from milling_twin.orchestrator.results import load_results, read_run_info

PI = math.pi


def cli(*args: str) -> list[str]:
    return ["run", *args]


def test_help(capsys):
    with pytest.raises(SystemExit) as info:
        main(["run", "--help"])
    assert info.value.code == 0
    out = capsys.readouterr().out
    assert "--fmu-dir" in out and "--out" in out and "--no-progress" in out


def test_run_prints_summary_and_writes_report(make_case, fmu_dir, tmp_path, capsys):
    code = main(cli(str(make_case()), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path / "runs"), "--no-progress"))
    out = capsys.readouterr().out
    assert code == 0, out
    run_dir = tmp_path / "runs" / "case"
    assert "completed: 4 steps to t = 0.4 s" in out and "steps/s" in out
    assert "power.P_total vs power" in out and "RMS error" in out and " kW " in out
    assert str(run_dir / "compare_power_P_total.png") in out and str(run_dir) in out
    assert (run_dir / "compare_power_P_total.png").stat().st_size > 10_000

    # by hand: simulated (see test_master) minus recorded (the CSV's kW column, in W)
    simulated = np.array([100, 100, 300 + 10 * PI + 50, 300 + 20 * PI + 100, 300 + 20 * PI])
    recorded = np.array([100.0, 380.0, 470.0, 360.0, 100.0])
    error = simulated - recorded
    report = json.loads((run_dir / "report.json").read_text())["comparisons"][0]
    assert report["simulated"] == "power.P_total" and report["recorded"] == "power"
    assert report["unit"] == "W" and report["display_unit"] == "kW" and report["n_samples"] == 5
    assert report["rms_error"] == pytest.approx(np.sqrt(np.mean(error**2)))
    assert report["mean_abs_error"] == pytest.approx(np.mean(np.abs(error)))
    assert report["max_error"] == pytest.approx(380.0 - 100.0)  # at t = 0.1 s
    assert report["mean_recorded"] == pytest.approx(282.0)
    assert report["relative_rms"] == pytest.approx(np.sqrt(np.mean(error**2)) / np.sqrt(np.mean(recorded**2)))


@pytest.mark.parametrize("edit, key", [
    (('fmu = "SpindlePower"', 'fmu = "Nope"'), "[fmus.power].fmu"),
    (('vy = { column = "vy"', 'vy = { column = "VY"'), "[recorded.channels].vy"),
])
def test_invalid_scenario_is_one_clean_line(make_case, fmu_dir, tmp_path, edit, key):
    path = make_case(edit)
    proc = subprocess.run([sys.executable, "-m", "milling_twin", "run", str(path), "--fmu-dir", str(fmu_dir),
                           "--out", str(tmp_path / "runs")], cwd=REPO_ROOT, capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stdout == ""
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: {path}: {key}: "), proc.stderr


def test_simulation_failure_exit_code(make_case, fmu_dir, tmp_path, capsys):
    csv = "speed,vx,vy,process,power\n0,0,0,Prep,0\n2000,0,0,Prep,0\n0,0,0,Prep,0\n"
    code = main(cli(str(make_case(csv=csv)), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path / "runs"),
                    "--no-progress"))
    err = capsys.readouterr().err
    assert code == 1 and err.startswith("error: SetFloat64 of instance 'power' at t = 0.1 s returned Error")
    assert "Traceback" not in err


def test_ctrl_c_stops_and_keeps_results(long_run):
    proc, run_dir = long_run
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=30)
    assert proc.returncode == 130, err
    assert out.startswith("interrupted: ") and "Traceback" not in err
    info = read_run_info(run_dir)
    assert info["status"] == "interrupted"
    frame = load_results(run_dir)
    assert len(frame) == info["rows_written"] > 0
    # stopped after a step; rows cover the output grid up to there (10 steps per row)
    assert (len(frame) - 1) * 10 <= info["steps"] < len(frame) * 10
    np.testing.assert_allclose(frame["time"].to_numpy(), np.arange(len(frame)) * 0.01, atol=1e-9)
