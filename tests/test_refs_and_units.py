""""instance.variable" parsed once (Ref.parse), units carried by the results (Parquet field metadata,
run.json, load_results' attrs) on both stepping paths and in the chunks of a killed run, and summaries
that show a quantity in its display unit."""
from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pyarrow.parquet as pq
import pytest

from conftest import LONG_TOML, REPO_ROOT, wait_for_first_chunk
from milling_twin.models.units import display_value, format_quantity
from milling_twin.orchestrator.calibrate.errors import CalibrationSpecError
from milling_twin.orchestrator.calibrate.report import summary_lines
from milling_twin.orchestrator.calibrate.result import ErrorRow
from milling_twin.orchestrator.calibrate.spec import load_spec
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.report import write_report
from milling_twin.orchestrator.results import RunWriter, load_results, read_run_info
from milling_twin.orchestrator.scenario import Ref, ScenarioError, load_scenario, with_values

# ---- Ref.parse ----


def test_ref_parse_splits_at_the_first_dot() -> None:
    assert Ref.parse("power.P_total") == Ref("power", "P_total")
    assert Ref.parse("wp.engagement[1,2]") == Ref("wp", "engagement[1,2]")
    assert Ref.parse("a.b.c") == Ref("a", "b.c")
    ref = Ref("power", "c1")
    assert Ref.parse(ref) is ref and str(ref) == "power.c1"


@pytest.mark.parametrize("text", ["power", "power.", ".P_total", "", None, 3, ["power.c1"]])
def test_ref_parse_rejects_what_is_no_reference(text) -> None:
    with pytest.raises(ValueError) as info:
        Ref.parse(text, "[[compare]][0].simulated")
    assert str(info.value) == f'[[compare]][0].simulated: expected "instance.variable", got {text!r}'


def test_ref_parse_raises_the_callers_error_naming_file_and_key(tmp_path: Path) -> None:
    def fail(key: str, message: str):
        raise ScenarioError(tmp_path / "x.toml", key, message)

    with pytest.raises(ScenarioError) as info:
        Ref.parse("power", "[[inputs]][1].to", fail)
    assert str(info.value) == f'{tmp_path / "x.toml"}: [[inputs]][1].to: expected "instance.variable", got \'power\''
    assert info.value.key == "[[inputs]][1].to"


def test_a_scenario_reference_without_a_variable_names_the_key(make_case, fmu_dir) -> None:
    path = make_case(('to = "power.mrr"', 'to = "power."'))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    assert str(info.value) == f'{path}: [[connections]][0].to: expected "instance.variable", got \'power.\''


def test_with_values_takes_refs_and_checks_strings(make_case, fmu_dir) -> None:
    sc = load_scenario(make_case(), fmu_dir)
    by_text = with_values(sc, {"power.c1": 0.5})
    by_ref = with_values(sc, {Ref("power", "c1"): 0.5})
    assert by_ref.instance("power").parameters == by_text.instance("power").parameters
    assert by_ref.instance("power").parameters["c1"] == 0.5
    with pytest.raises(ScenarioError) as info:
        with_values(sc, {"power": 1.0})
    assert str(info.value).endswith("""with_values['power']: expected "instance.variable", got 'power'""")
    with pytest.raises(ScenarioError) as info:  # the same message for a Ref key as for its text
        with_values(sc, {Ref("drill", "c3"): 1.0})
    assert str(info.value).endswith("with_values['drill.c3']: unknown instance 'drill'; instances: mrr, power")


def test_spec_references_are_parsed_once_naming_the_key(tmp_path: Path) -> None:
    spec = load_spec(REPO_ROOT / "scenarios" / "calibration" / "umich_power.toml")
    assert spec.parameters[0].ref == Ref("power", "P_standby") and spec.parameters[0].name == "power.P_standby"
    assert spec.outputs[0].simulated == Ref("power", "P_total")
    assert spec.alignment.simulated[0] == Ref("power", "spindle_speed")
    assert spec.input_floors == {Ref("power", "mrr"): 1e-300}
    text = (REPO_ROOT / "scenarios" / "calibration" / "umich_power.toml").read_text()
    scenario = (REPO_ROOT / "scenarios" / "umich_power.toml").resolve()
    for old, new, key in (('[parameters."power.c1"]', '[parameters."c1"]', '[parameters."c1"]'),
                          ('simulated = "power.P_total"', 'simulated = "P_total"', "[[outputs]][0].simulated"),
                          ('"power.spindle_speed", "mrr', '"spindle_speed", "mrr', "[alignment].simulated[0]"),
                          ('[inputs."power.mrr"]', '[inputs."mrr"]', '[inputs."mrr"]')):
        bad = tmp_path / "bad.toml"
        bad.write_text(text.replace(old, new, 1).replace('scenario = "../umich_power.toml"', f'scenario = "{scenario}"')
                       .replace('calibrated_scenario = "umich_power_calibrated.toml"', ""))
        with pytest.raises(CalibrationSpecError) as info:
            load_spec(bad)
        assert str(info.value).startswith(f'{bad}: {key}: expected "instance.variable", got '), str(info.value)


# ---- units of the results ----

CASE_UNITS = {"time": {"unit": "s"}, "power.P_total": {"unit": "W", "display_unit": "kW"},
              "mrr.mrr": {"unit": "m3/s", "display_unit": "cm3/min"}, "power.spindle_on": {"unit": "bool"}}


def assert_units(run_dir: Path, expected: dict) -> None:
    """Every chunk's field metadata, run.json and load_results' attrs say ``expected``."""
    chunks = sorted((run_dir / "chunks").glob("chunk_*.parquet"))
    assert chunks
    for chunk in chunks:
        schema = pq.read_schema(chunk)
        for column, units in expected.items():
            metadata = schema.field(column).metadata or {}
            assert metadata == {k.encode(): v.encode() for k, v in units.items()}, (chunk.name, column)
    assert read_run_info(run_dir)["units"] == expected
    frame = load_results(run_dir)
    assert frame.attrs["units"] == {c: u["unit"] for c, u in expected.items()}
    assert frame.attrs["display_units"] == {c: u["display_unit"] for c, u in expected.items() if "display_unit" in u}


@pytest.mark.parametrize("fmi", [3, 2])
@pytest.mark.parametrize("stepping", ["python", "fast"])
def test_results_carry_units_on_both_paths(make_case, fmu_dir, tmp_path, stepping, fmi) -> None:
    scenario = load_scenario(make_case(("fmi = 3", f"fmi = {fmi}"), ("fmi = 3", f"fmi = {fmi}")), fmu_dir)
    assert {i.fmi_version for i in scenario.instances} == {fmi}
    result = run(scenario, tmp_path / stepping, progress=False, stepping=stepping, flush_rows=2)
    assert result.stepping == stepping and result.rows == 5
    assert list(load_results(result.run_dir).columns) == list(CASE_UNITS)
    assert len(list((result.run_dir / "chunks").glob("*.parquet"))) == 3
    assert_units(result.run_dir, CASE_UNITS)


def test_a_run_without_chunks_takes_its_units_from_run_json(tmp_path) -> None:
    writer = RunWriter(tmp_path, ["time", "p.P"], units={"time": {"unit": "s"},
                                                          "p.P": {"unit": "W", "display_unit": "kW"}})
    frame = load_results(tmp_path)
    assert frame.attrs == {"units": {"time": "s", "p.P": "W"}, "display_units": {"p.P": "kW"}}
    writer.append([0.0, 1500.0])
    writer.finish("completed")
    frame = load_results(tmp_path)
    assert frame["p.P"].tolist() == [1500.0]  # SI
    assert frame.attrs == {"units": {"time": "s", "p.P": "W"}, "display_units": {"p.P": "kW"}}


def test_a_writer_without_units_writes_none(tmp_path) -> None:
    writer = RunWriter(tmp_path, ["time", "a.x"])
    writer.append([0.0, 1.0])
    writer.finish("completed")
    assert pq.read_schema(next((tmp_path / "chunks").glob("*.parquet"))).field("a.x").metadata is None
    assert load_results(tmp_path).attrs == {"units": {"time": "", "a.x": ""}, "display_units": {}}


RUN_SCRIPT = """
import sys
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.scenario import load_scenario
run(load_scenario(sys.argv[1], sys.argv[2]), sys.argv[3], progress=False, stepping=sys.argv[4], flush_rows=500)
"""


@pytest.mark.parametrize("stepping", ["python", "fast"])
def test_the_chunks_of_a_killed_run_carry_units(fmu_dir, tmp_path, stepping) -> None:
    scenario = tmp_path / "long.toml"
    scenario.write_text(LONG_TOML)
    out = tmp_path / "runs"
    proc = subprocess.Popen([sys.executable, "-c", RUN_SCRIPT, str(scenario), str(fmu_dir), str(out), stepping],
                            cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "TMPDIR": str(tmp_path)})  # LD_PRELOAD of the sanitizer stage too
    run_dir = out / "long"
    try:
        wait_for_first_chunk(proc, run_dir)
        deadline = time.monotonic() + 60
        while len(list((run_dir / "chunks").glob("chunk_*.parquet"))) < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.communicate()
    assert json.loads((run_dir / "run.json").read_text())["status"] == "running"
    assert_units(run_dir, {"time": {"unit": "s"}, "power.P_total": {"unit": "W", "display_unit": "kW"},
                           "power.spindle_on": {"unit": "bool"}})
    assert (load_results(run_dir)["power.P_total"] == 300.0).all()  # W: the values stay SI


# ---- summaries in the display unit ----


def test_format_quantity_in_the_display_unit() -> None:
    assert format_quantity(1234.5, "W") == "1.234 kW"
    assert format_quantity(0.5, "kW") == "0.5 kW"
    assert format_quantity(2.0, "N") == "2 N" and format_quantity(0.25, "1") == "0.25"
    assert format_quantity(0.012, "m", "um") == "1.2e+04 um"
    assert format_quantity(3.0, "W", "mm") == "3 W"  # a display unit that does not fit: the unit itself
    assert format_quantity(1.0, "W.s/rad") == "1 W.s/rad" and format_quantity(7.0, "furlong") == "7 furlong"
    assert display_value(250.0, "W") == (0.25, "kW")


def test_the_calibration_summary_shows_a_comparison_in_the_run_summarys_unit(make_case, fmu_dir, tmp_path) -> None:
    """The run summary shows P_total's comparison in kW; a calibration of the same output whose spec reports
    it in W prints its summary lines in kW too, with the same numbers."""
    scenario = load_scenario(make_case(), fmu_dir)
    result = run(scenario, tmp_path, progress=False)
    comparison = write_report(scenario, result.run_dir).comparisons[0]
    assert (comparison.unit, comparison.display_unit) == ("W", "kW")
    rms_w = comparison.rms_error
    row = ErrorRow("power.P_total", "learning", "", 5, "W", 2 * rms_w, rms_w, 0.2, 0.1, 0.5, 0.9, 0.0, 1.0, 3.0)
    fake = SimpleNamespace(spec=SimpleNamespace(name="c", kind="scenario"),
                           fit=SimpleNamespace(parameters=[], starts=[], solve_time=0.1, derivatives="exact",
                                               statistics=SimpleNamespace(parameters=[])), errors=[row])
    line = summary_lines(fake)[-1]
    in_kw = format_quantity(rms_w, comparison.unit, comparison.display_unit)
    assert in_kw.endswith(" kW")
    assert f"RMS error {2 * rms_w / 1000:.4g} -> {in_kw} (20.00 % -> 10.00 %" in line, line
    assert " W " not in line and " W (" not in line
