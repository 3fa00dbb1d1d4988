"""Parameter changes at events (``[[on_change]]``, orchestrator/master.py's docstring): an Interpolator running a
program with tool changes (T1 M6 ... T2 M6 ... T1 M6) drives SpindlePower, whose tunable parameters the entries
change. The new values act from the step at the communication point where the output changed; the Python loop
and the compiled stepper are bit-identical (FMI 3 and 2, with [stepping], with chunks ending at and around the
events); run.json and the summary report the events; the refusals name the file and the key; the entries write
back as TOML (also through the part expansion's writer)."""
from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import bits, run_both
from milling_twin.cli import main
from milling_twin.orchestrator import fastpath
from milling_twin.orchestrator.master import FiredEvent, run
from milling_twin.orchestrator.part import expand
from milling_twin.orchestrator.results import load_results, read_run_info
from milling_twin.orchestrator.scenario import OnChange, Ref, ScenarioError, load_scenario, on_change_toml

PROGRAM = """G21 G90 G17
T1 M6
S6000 M3
G1 X3 F3000
T2 M6
G1 X6
T1 M6
G1 X8
M30
"""
TOOLS = """T1 P1 D10.000 Z+50.000 ; 10 mm end mill flutes=3
T2 P2 D6.000 Z+60.000 ; 6 mm end mill flutes=2
"""
ENTRIES = """
[[on_change]]
output = "interp.tool_number"
equals = 2
set = { "power.P_idle" = { value = 0.5, unit = "kW" }, "power.c1" = 0.1 }

[[on_change]]
output = "interp.tool_number"
equals = 1
set = { "power.P_idle" = 200.0 }

[[on_change]]
output = "interp.finished"
equals = true
set = { "power.P_standby" = 100.0 }
"""
SCENARIO = """[scenario]
name = "on_change"
stop_time = 0.3
output_interval = 1e-4

[fmus.interp]
fmu = "Interpolator"
step_size = 1e-3
[fmus.interp.parameters]
program = { path = "part.nc" }
tool_table = { path = "tool.tbl" }

[fmus.power]
fmu = "SpindlePower"
step_size = 1e-4

[[connections]]
from = "interp.spindle_speed"
to = "power.spindle_speed"
[[connections]]
from = "interp.spindle_on"
to = "power.spindle_on"

[outputs]
record = ["interp.tool_number", "interp.finished", "interp.spindle_speed", "power.P_total"]
"""
# power variable: fine while the tool is within 2 mm of the start, coarse afterwards (where the events lie)
STEPPING = """
[stepping]
coarse_step = 1e-3
variable = ["power"]
fine_when = [{ output = "interp.x", below = { value = 2.0, unit = "mm" } }]
"""
M = 10  # ticks per Interpolator step (1 ms on the 0.1 ms base grid)
P_IDLE, C1, P_STANDBY = 200.0, 0.3, 500.0  # SpindlePower's start values


def write(folder: Path, entries: str = ENTRIES, fmi: int = 3, extra: str = "") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "part.nc").write_text(PROGRAM)
    (folder / "tool.tbl").write_text(TOOLS)
    text = SCENARIO + extra + entries
    if fmi == 2:
        for model in ("Interpolator", "SpindlePower"):
            text = text.replace(f'fmu = "{model}"', f'fmu = "{model}"\nfmi = 2')
    path = folder / "case.toml"
    path.write_text(text)
    return path




def assert_identical(both: dict) -> None:
    (rp, fp), (rf, ff) = both["python"], both["fast"]
    assert list(fp.columns) == list(ff.columns) and fp.shape == ff.shape and len(fp) > 1
    np.testing.assert_array_equal(bits(fp), bits(ff))
    assert rp.events == rf.events and len(rp.events) == 4
    assert (rp.steps, rp.fmu_steps, rp.rows, rp.fine_intervals, rp.coarse_intervals) == \
           (rf.steps, rf.fmu_steps, rf.rows, rf.fine_intervals, rf.coarse_intervals)


@pytest.fixture(scope="module")
def runs(fmu_dir, tmp_path_factory) -> dict:
    """The scenario with its entries on both paths, and without them (the reference)."""
    out = tmp_path_factory.mktemp("on_change")
    scenario = load_scenario(write(out / "case"), fmu_dir)
    return {"scenario": scenario, "events": run_both(scenario, out / "events"),
            "none": run(dataclasses.replace(scenario, on_change=()), out / "none", progress=False,
                        stepping="python")}


def expected_events(frame, base: float) -> list[FiredEvent]:
    """From the recorded outputs: each change of the tool number (to 1 or 2) and of finished (to true), at the end
    of the Interpolator step whose row first shows it (row i lies in the step ending at tick ceil(i / M) * M)."""
    events = []
    for column, entries in (("interp.tool_number", {2: 0, 1: 1}), ("interp.finished", {True: 2})):
        values = frame[column].to_numpy()
        for i in np.flatnonzero(values[1:] != values[:-1]) + 1:
            value = values[i].item()
            if value in entries:
                events.append(FiredEvent(0.0 + math.ceil(i / M) * M * base, column, value, entries[value]))
    return sorted(events, key=lambda e: (e.time, e.entry))


def test_the_values_act_from_the_step_at_the_event(runs):
    """Before the tool-2 event (and at its row: the power's step ending there) the power is that of the run
    without entries, bit for bit (tool 1 at 1 ms sets P_idle to its own value); from the next row on it differs
    by the changed terms: P_idle + c1 |n| while tool 2 is in, c1 |n| after tool 1 is back, and P_standby from
    the end of the program on."""
    scenario, (result, frame) = runs["scenario"], runs["events"]["python"]
    events = expected_events(frame, scenario.base_step)
    assert result.events == tuple(events)
    assert [(e.output, e.value) for e in events] == [("interp.tool_number", 1), ("interp.tool_number", 2),
                                                     ("interp.tool_number", 1), ("interp.finished", True)]
    reference = load_results(runs["none"].run_dir)
    time, power = frame["time"].to_numpy(), frame["power.P_total"].to_numpy()
    delta = power - reference["power.P_total"].to_numpy()
    tool2, tool1, finished = (round(e.time / scenario.base_step) for e in events[1:])  # rows = ticks here
    assert 0 < tool2 < tool1 < finished < len(frame) - 1 and time[tool2] == events[1].time
    np.testing.assert_array_equal(bits(frame[: tool2 + 1]), bits(reference[: tool2 + 1]))
    speed = np.abs(frame["interp.spindle_speed"].to_numpy()[tool2:])
    assert speed.min() == speed.max() == pytest.approx(6000 * 2 * np.pi / 60)  # 6000 rpm throughout
    n = speed[0]
    np.testing.assert_allclose(delta[tool2 + 1: tool1 + 1], (500.0 - P_IDLE) + (0.1 - C1) * n, rtol=1e-12)
    np.testing.assert_allclose(delta[tool1 + 1: finished + 1], (0.1 - C1) * n, rtol=1e-12)
    np.testing.assert_allclose(delta[finished + 1:], (0.1 - C1) * n + (100.0 - P_STANDBY), rtol=1e-12)


def test_python_and_fast_path_bit_identical(runs):
    assert_identical(runs["events"])


def test_fmi2_instances_bit_identical(fmu_dir, tmp_path):
    scenario = load_scenario(write(tmp_path, fmi=2), fmu_dir)
    assert {inst.fmi_version for inst in scenario.instances} == {2}
    both = run_both(scenario, tmp_path / "runs")
    assert_identical(both)
    assert both["fast"][0].events == tuple(expected_events(both["fast"][1], scenario.base_step))


def test_with_stepping_bit_identical_and_the_same_events(runs, fmu_dir, tmp_path):
    """The power a variable instance, coarse where the events lie: the entries fire at the same ticks (the
    Interpolator keeps its step), before the power's coarse step from there."""
    scenario = load_scenario(write(tmp_path, extra=STEPPING), fmu_dir)
    both = run_both(scenario, tmp_path / "runs")
    assert_identical(both)
    result = both["fast"][0]
    assert result.fine_intervals > 10 and result.coarse_intervals > 100
    assert result.events == runs["events"]["python"][0].events


def test_chunks_ending_at_and_around_events_change_nothing(runs, fmu_dir, tmp_path, monkeypatch):
    """Chunks of 7 ticks: the tool-2 event (tick 910 = 130 x 7) falls on a chunk's first tick, the others inside
    chunks; each costs one return to Python, which resumes the same chunk from the event's tick."""
    calls = []
    original = fastpath.Stepper.run_chunk

    def run_chunk(self, first, last):
        out = original(self, first, last)
        calls.append((first, last, out.code, out.tick))
        return out

    monkeypatch.setattr(fastpath, "FIRST_CHUNK_TICKS", 7)
    monkeypatch.setattr(fastpath.Stepper, "max_ticks", lambda self: 7)
    monkeypatch.setattr(fastpath.Stepper, "run_chunk", run_chunk)
    result = run(runs["scenario"], tmp_path, progress=False, stepping="fast")
    python, frame = runs["events"]["python"]
    np.testing.assert_array_equal(bits(load_results(result.run_dir)), bits(frame))
    assert result.events == python.events
    events = [(i, c) for i, c in enumerate(calls) if c[2] == fastpath.EVENT]
    assert [c[3] for _, c in events] == [round(e.time / runs["scenario"].base_step) for e in python.events]
    assert any(first == tick for _, (first, _, _, tick) in events)  # at a chunk's first tick
    assert any(first < tick < last for _, (first, last, _, tick) in events)  # inside a chunk
    for i, (_, last, _, tick) in events:  # resumed at the event's tick, to the same end
        assert calls[i + 1][:2] == (tick, last) and calls[i + 1][2] != fastpath.EVENT


def test_run_json_lists_the_events_and_the_summary_counts_them(runs, fmu_dir, tmp_path, capsys):
    for path in ("python", "fast"):
        result = runs["events"][path][0]
        info = read_run_info(result.run_dir)["on_change"]
        assert info["events"] == [{"time": e.time, "output": e.output, "value": e.value, "entry": e.entry}
                                  for e in result.events]
        assert info["entries"][0] == {"output": "interp.tool_number", "equals": 2,
                                      "set": {"power.P_idle": 500.0, "power.c1": 0.1}}
    code = main(["run", str(write(tmp_path / "cli")), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path / "out"),
                 "--no-progress"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "on_change: 4 events fired (3 entries)" in out.splitlines()


def test_the_entries_are_read_in_si_and_in_order(runs):
    assert runs["scenario"].on_change == (
        OnChange(Ref("interp", "tool_number"), 2, ((Ref("power", "P_idle"), 500.0), (Ref("power", "c1"), 0.1))),
        OnChange(Ref("interp", "tool_number"), 1, ((Ref("power", "P_idle"), 200.0),)),
        OnChange(Ref("interp", "finished"), True, ((Ref("power", "P_standby"), 100.0),)))


def test_the_entries_write_back_as_toml(runs, fmu_dir, tmp_path):
    """on_change_toml of the entries' tables reads back to the same entries; the part expansion's writer gives
    [[on_change]] blocks that read back as the tables it was given (units and all)."""
    scenario = runs["scenario"]
    text = on_change_toml([e.table() for e in scenario.on_change])
    assert load_scenario(write(tmp_path, entries="\n" + text), fmu_dir).on_change == scenario.on_change
    written = tomllib.loads(ENTRIES)["on_change"]
    doc = {"scenario": {"name": "x"}, "on_change": written, "outputs": {"record": ["interp.x"]}}
    assert tomllib.loads(expand.scenario_toml(doc)) == doc


BAD = {
    "fixed target": ('"power.c1" = 0.1', '"interp.acceleration" = 1.0', '[[on_change]][0].set."interp.acceleration"',
                     "interp.acceleration is a fixed parameter of Interpolator: only tunable parameters may change "
                     "during a run"),
    "unknown output": ('"interp.tool_number"\nequals = 2', '"interp.tool"\nequals = 2', "[[on_change]][0].output",
                       "unknown variable 'tool' in interp (Interpolator); known outputs: "),
    "Float64 output": ('"interp.tool_number"\nequals = 2', '"interp.feed"\nequals = 2', "[[on_change]][0].output",
                       "interp.feed is a Real/Float64 output: a trigger must be an Int32 or Boolean output"),
    "an input as output": ('"interp.tool_number"\nequals = 2', '"power.mrr"\nequals = 2', "[[on_change]][0].output",
                           "power.mrr is an input, not an output"),
    "unknown instance": ('"power.c1"', '"pwr.c1"', '[[on_change]][0].set."pwr.c1"',
                         "unknown instance 'pwr'; instances: interp, power"),
    "unknown variable": ('"power.c1"', '"power.c9"', '[[on_change]][0].set."power.c9"',
                         "unknown variable 'c9' in SpindlePower; known parameters: P_standby"),
    "not instance.variable": ('"power.c1"', '"c1"', '[[on_change]][0].set.c1', 'expected "instance.variable"'),
    "an input as target": ('"power.c1" = 0.1', '"power.mrr" = 0.1', '[[on_change]][0].set."power.mrr"',
                           "input variable 'mrr' in SpindlePower; known parameters"),
    "out of range": ('"power.c1" = 0.1', '"power.c1" = -1.0', '[[on_change]][0].set."power.c1"',
                     "-1.0 W.s/rad is outside the range [0.0, 1000.0] W.s/rad that SpindlePower allows for 'c1'"),
    "unit of another dimension": ('unit = "kW"', 'unit = "mm"', '[[on_change]][0].set."power.P_idle"',
                                  "unit 'mm' does not fit 'P_idle' (unit 'W')"),
    "Boolean equals a number": ("equals = true", "equals = 1", "[[on_change]][2].equals",
                                "interp.finished is Boolean: give equals = true or false, got 1"),
    "Int32 equals a float": ("equals = 2\n", "equals = 2.0\n", "[[on_change]][0].equals",
                             "interp.tool_number is an Int32: give a whole number, got 2.0"),
    "no equals": ("equals = 2\n", "", "[[on_change]][0].equals", "missing required key"),
    "empty set": ('set = { "power.P_standby" = 100.0 }', "set = {}", "[[on_change]][2].set",
                  'expected a table of at least one "instance.variable" = value, got {}'),
    "unknown key": ("equals = 2\n", "equals = 2\nvalue = 3\n", "[[on_change]][0].value",
                    "unknown key 'value'; known keys: output, equals, set"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_a_bad_entry_names_file_and_key(fmu_dir, tmp_path, case):
    old, new, key, message = BAD[case]
    assert old in ENTRIES
    path = write(tmp_path, ENTRIES.replace(old, new, 1))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    assert (info.value.path, info.value.key) == (path, key), str(info.value)
    assert str(info.value).startswith(f"{path}: {key}: ") and message in info.value.detail, str(info.value)


def test_a_variable_instance_cannot_trigger(fmu_dir, tmp_path):
    """A trigger's instance keeps its own step grid: here the Interpolator is a variable instance of [stepping]
    (gated by a second Interpolator), so its tool number cannot trigger; the gate's can."""
    gate = ('\n[fmus.gate]\nfmu = "Interpolator"\nstep_size = 1e-3\n[fmus.gate.parameters]\n'
            'program = { path = "part.nc" }\ntool_table = { path = "tool.tbl" }\n')
    stepping = ('\n[stepping]\ncoarse_step = 1e-3\nvariable = ["interp"]\n'
                'fine_when = [{ output = "gate.spindle_on", is = true }]\n')
    path = write(tmp_path)
    text = path.read_text().replace("\n[fmus.interp]", gate + "\n[fmus.interp]", 1)  # the gate steps first
    path.write_text(text.replace("\n[[on_change]]", stepping + "\n[[on_change]]", 1))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    assert info.value.key == "[[on_change]][0].output", str(info.value)
    assert info.value.detail == ("instance 'interp' is a variable instance of [stepping]: a trigger's instance must "
                                 "keep its own step grid")
    path.write_text(path.read_text().replace('output = "interp.', 'output = "gate.'))
    assert [e.output.instance for e in load_scenario(path, fmu_dir).on_change] == ["gate"] * 3

