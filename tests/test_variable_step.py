"""The engagement-driven variable communication step (``[stepping]``, orchestrator/master.py's docstring): the
Python loop and the compiled stepper bit-identical, also across chunk boundaries inside a coarse interval; the
same results in the cut as with every interval fine, in fewer doSteps; the counts; and the refusals of
``[stepping]`` tables that cannot work, each naming the file and the key."""
from __future__ import annotations

import dataclasses
import zipfile
from pathlib import Path

import numpy as np
import pytest

from conftest import REPO_ROOT
from fmu_helpers import bits, run_both
from milling_twin.cli import main
from milling_twin.orchestrator import fastpath
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.results import load_results, read_run_info
from milling_twin.orchestrator.scenario import ScenarioError, load_scenario

SCENARIO = REPO_ROOT / "scenarios" / "slot_entry_variable.toml"
TEXT = SCENARIO.read_text()
STEPPING = TEXT[TEXT.index("\n[stepping]\n") + 1:]  # the scenario's own table (the end of the file)


def table(*conditions: str) -> str:
    """A [stepping] table with the scenario's coarse step and variable instances and these conditions."""
    lines = "".join(f"  {{ {c} }},\n" for c in conditions)
    return f'[stepping]\ncoarse_step = 1e-3\nvariable = ["force", "vibration"]\nfine_when = [\n{lines}]\n'


BASE = table('output = "workpiece.axial_depth", above = 0.0')
N_TICKS, M = 15_000, 100  # 0.15 s at 10 us; coarse intervals of 1 ms
INTERVALS = N_TICKS // M
IN_CUT = ["force.Fx", "force.Fy", "force.torque", "vibration.tip_displacement_x", "vibration.tip_displacement_y"]


@pytest.fixture(autouse=True)
def library(fmu_dir):
    path, reason = fastpath.find_library(load_scenario(SCENARIO, fmu_dir))
    if path is None:
        pytest.fail(f"{reason}; build it with cmake --build {REPO_ROOT / 'build'}")
    return fastpath.load_library(path.resolve())


def write(tmp_path: Path, stepping: str | None = None, fmi: int = 3, name: str = "case.toml") -> Path:
    """The test scenario in ``tmp_path`` (its program found where it lies), with ``stepping`` as its
    [stepping] table ("" for none) and every instance on FMI ``fmi``."""
    text = TEXT.replace('{ path = "programs/slot_entry.nc" }',
                        f'{{ path = "{REPO_ROOT / "scenarios" / "programs" / "slot_entry.nc"}" }}')
    if stepping is not None:
        text = text.replace(STEPPING, stepping)
    if fmi == 2:
        for model in ("Interpolator", "Workpiece", "CuttingForce", "ToolVibration"):
            text = text.replace(f'fmu = "{model}"', f'fmu = "{model}"\nfmi = 2')
    path = tmp_path / name
    path.write_text(text)
    return path




def assert_identical(both: dict) -> None:
    (rp, fp), (rf, ff) = both["python"], both["fast"]
    assert list(fp.columns) == list(ff.columns) and fp.shape == ff.shape and len(fp) > 1
    for column in fp.columns:  # every recorded column, bit for bit
        assert np.array_equal(fp[column].to_numpy(np.float64).view(np.uint64),
                              ff[column].to_numpy(np.float64).view(np.uint64)), column
    assert (rp.steps, rp.fmu_steps, rp.rows, rp.fine_intervals, rp.coarse_intervals) == \
           (rf.steps, rf.fmu_steps, rf.rows, rf.fine_intervals, rf.coarse_intervals)


@pytest.fixture(scope="module")
def runs(fmu_dir, tmp_path_factory) -> dict:
    """The test scenario with and without [stepping], on both paths."""
    out = tmp_path_factory.mktemp("variable_step")
    scenario = load_scenario(SCENARIO, fmu_dir)
    return {"variable": run_both(scenario, out / "variable"),
            "fine": run_both(dataclasses.replace(scenario, stepping=None), out / "fine")}


# ---- both paths ----


def test_python_and_fast_path_bit_identical_with_stepping(runs):
    assert_identical(runs["variable"])
    assert_identical(runs["fine"])
    result = runs["variable"]["fast"][0]
    assert 0 < result.fine_intervals < INTERVALS and result.fine_intervals + result.coarse_intervals == INTERVALS


def test_fmi2_instances_bit_identical(fmu_dir, tmp_path):
    scenario = load_scenario(write(tmp_path, fmi=2), fmu_dir)
    assert {inst.fmi_version for inst in scenario.instances} == {2}
    both = run_both(scenario, tmp_path / "runs")
    assert_identical(both)
    assert both["fast"][0].coarse_intervals > 0 and both["fast"][0].fine_intervals > 0


def test_chunks_ending_inside_coarse_intervals_change_nothing(runs, fmu_dir, tmp_path, monkeypatch):
    """The fast path cut into chunks of at most 37 ticks: most chunks end inside a 100-tick interval, many of
    them coarse; the plan carries the interval's state across."""
    boundaries = []
    original = fastpath.Stepper.run_chunk

    def run_chunk(self, first, last):
        if first % M:
            boundaries.append((first, self._plan.fine))
        return original(self, first, last)

    monkeypatch.setattr(fastpath, "FIRST_CHUNK_TICKS", 37)
    monkeypatch.setattr(fastpath.Stepper, "max_ticks", lambda self: 37)
    monkeypatch.setattr(fastpath.Stepper, "run_chunk", run_chunk)
    result = run(load_scenario(SCENARIO, fmu_dir), tmp_path, progress=False, stepping="fast")
    assert sum(1 for _, fine in boundaries if not fine) > 50 and sum(1 for _, fine in boundaries if fine) > 50
    python, frame = runs["variable"]["python"][0], load_results(result.run_dir)
    np.testing.assert_array_equal(bits(frame), bits(runs["variable"]["python"][1]))
    assert (result.fmu_steps, result.fine_intervals, result.coarse_intervals) == \
           (python.fmu_steps, python.fine_intervals, python.coarse_intervals)


# ---- against every interval fine ----


def test_the_cut_agrees_with_every_interval_fine_in_fewer_do_steps(runs):
    (variable, fv), (fine, ff) = runs["variable"]["python"], runs["fine"]["python"]
    cut = ff["workpiece.axial_depth"].to_numpy() > 0
    assert 100 < cut.sum() < len(ff) - 100  # in air for part of the run, then cutting
    assert np.abs(ff["force.Fx"].to_numpy()[cut]).max() > 50.0  # newtons: a real cut
    for column in IN_CUT:
        reference, got = ff[column].to_numpy()[cut], fv[column].to_numpy()[cut]
        rms = np.sqrt(np.mean(reference ** 2))
        assert rms > 0 and np.sqrt(np.mean((got - reference) ** 2)) < 0.01 * rms, column
    for column in [c for c in ff.columns if c.startswith(("workpiece.", "interp."))]:
        np.testing.assert_array_equal(fv[column].to_numpy(), ff[column].to_numpy())
    # interp and workpiece: one step per interval; force and vibration: 100 in a fine interval, 1 in a coarse one
    assert fine.fmu_steps == 2 * INTERVALS + 2 * N_TICKS
    assert variable.fmu_steps == 2 * INTERVALS + 2 * (M * variable.fine_intervals + variable.coarse_intervals)
    assert variable.fmu_steps < fine.fmu_steps
    assert (fine.fine_intervals, fine.coarse_intervals) == (0, 0)


def test_rows_in_a_coarse_interval_hold_the_coarse_step_and_the_entry_is_fine(runs):
    """Rows inside a coarse interval hold the variable instances' outputs from its one step; the interval in
    which the Workpiece first reports material is fine (its depth at the interval's end), and so is every one
    after it (the tool stays in material): the coarse intervals are the first ones."""
    (result, frame) = runs["variable"]["python"]
    angle = frame["force.spindle_angle"].to_numpy()
    depth = frame["workpiece.axial_depth"].to_numpy()
    first_cut = int(np.argmax(depth > 0))  # the row at the end of the first interval in material
    entry = (first_cut - 1) // 10  # rows 10c+1 .. 10c+10 lie in interval c
    coarse = result.coarse_intervals
    assert 10 < coarse <= entry
    for c in range(coarse):  # coarse: one value per interval
        assert len(set(angle[10 * c + 1:10 * c + 11])) == 1, c
    for c in range(coarse, INTERVALS):  # fine: a new value each row
        assert len(set(angle[10 * c + 1:10 * c + 11])) == 10, c


# ---- the counts ----


def test_a_condition_that_never_holds_leaves_every_interval_coarse(fmu_dir, tmp_path):
    """Every interval coarse: force and vibration make one doStep per interval, as interp and workpiece; the
    run ends 0.5 ms into its last interval (0.1505 s), whose steps end there."""
    stepping = table('output = "workpiece.axial_depth", above = { value = 1.0, unit = "m" }')
    scenario = dataclasses.replace(load_scenario(write(tmp_path, stepping), fmu_dir), stop_time=0.1505)
    both = run_both(scenario, tmp_path / "runs")
    assert_identical(both)
    result, intervals = both["fast"][0], INTERVALS + 1
    assert result.steps == N_TICKS + M // 2 and result.end_time == pytest.approx(0.1505)
    assert (result.fine_intervals, result.coarse_intervals) == (0, intervals)
    assert result.fmu_steps == 4 * intervals
    info = read_run_info(result.run_dir)["stepping"]["variable_step"]
    assert info == {"coarse_step": 0.001, "ticks_per_interval": M, "variable": ["force", "vibration"],
                    "fine_when": [{"output": "workpiece.axial_depth", "above": 1.0}],
                    "hold_intervals": 1, "fine_intervals": 0, "coarse_intervals": intervals}


def test_should_stop_inside_a_coarse_interval_same_on_both_paths(fmu_dir, tmp_path):
    """should_stop at a row inside a coarse interval ends the run after that tick on both paths alike."""
    scenario = load_scenario(SCENARIO, fmu_dir)
    results = {}
    for path in ("python", "fast"):
        result = run(scenario, tmp_path / path, progress=False, stepping=path, should_stop=lambda t: t > 0.0303)
        results[path] = result, load_results(result.run_dir)
    (rp, fp), (rf, ff) = results["python"], results["fast"]
    assert rp.status == rf.status == "interrupted" and rp.steps == rf.steps == 3030
    np.testing.assert_array_equal(bits(fp), bits(ff))
    assert (rp.fmu_steps, rp.fine_intervals, rp.coarse_intervals) == (rf.fmu_steps, 0, 31)
    assert rf.fmu_steps == 2 * 31 + 2 * 31  # interp, workpiece, force, vibration: one step each per interval


@pytest.mark.parametrize("hold, after", [("", 1), ("hold = 5e-3\n", 5), ('hold = { value = 4.2, unit = "ms" }\n', 5),
                                         ("hold = 1e-3\n", 1)])
def test_the_intervals_after_the_condition_stops_holding_are_fine(runs, fmu_dir, tmp_path, hold, after):
    """``interp.x below -13 mm`` holds at the end of the intervals while the tool is further back; the first
    interval at whose end it no longer holds is fine too (it held at its start), and with ``hold`` the intervals
    up to that long after it (rounded up to whole intervals), the rest coarse."""
    x = runs["fine"]["python"][1]["interp.x"].to_numpy()[10::10]  # at the end of each interval
    held = int(np.sum(x < -0.013))
    assert 10 < held < INTERVALS - 10 and np.all(np.diff(x) >= 0)
    stepping = table('output = "interp.x", below = { value = -13.0, unit = "mm" }') + hold
    scenario = load_scenario(write(tmp_path, stepping), fmu_dir)
    assert scenario.stepping.hold_intervals == after
    both = run_both(scenario, tmp_path / "runs")
    assert_identical(both)
    fine = held + after
    assert (both["fast"][0].fine_intervals, both["fast"][0].coarse_intervals) == (fine, INTERVALS - fine)
    angle = both["python"][1]["force.spindle_angle"].to_numpy()
    assert len(set(angle[10 * (fine - 1) + 1:10 * fine + 1])) == 10  # the last fine interval: a value a row
    assert len(set(angle[10 * fine + 1:10 * fine + 11])) == 1  # the first coarse one: one step


@pytest.mark.parametrize("gap", [2, 5])
def test_a_hold_restarts_when_the_condition_holds_again(runs, fmu_dir, tmp_path, monkeypatch, gap):
    """``interp.x`` below -13 mm, or above a threshold ``gap`` intervals further on, with a hold of 3 intervals:
    interval c is fine when a condition held at one of the evaluations c-3..c, so a gap of 2 stays fine
    throughout and a gap of 5 has 2 coarse intervals; the fast path cut into chunks of 37 ticks carries the
    hold's count across and gives the Python loop's rows and counts bit for bit."""
    x = runs["fine"]["python"][1]["interp.x"].to_numpy()[10::10]  # at the end of each interval
    first = int(np.argmax(x >= -0.013))
    assert np.all(np.diff(x[first - 1:first + gap + 1]) > 0)
    threshold = float(0.5 * (x[first + gap - 1] + x[first + gap]))  # m: false at the gap's intervals, true after
    holds = (x < -0.013) | (x > threshold)
    expected = sum(bool(holds[max(0, c - 3):c + 1].any()) for c in range(INTERVALS))
    assert expected == INTERVALS - max(0, gap - 3)
    stepping = table('output = "interp.x", below = { value = -13.0, unit = "mm" }',
                     f'output = "interp.x", above = {threshold!r}') + "hold = 3e-3\n"
    monkeypatch.setattr(fastpath, "FIRST_CHUNK_TICKS", 37)
    monkeypatch.setattr(fastpath.Stepper, "max_ticks", lambda self: 37)
    both = run_both(load_scenario(write(tmp_path, stepping), fmu_dir), tmp_path / "runs")
    assert_identical(both)
    assert (both["fast"][0].fine_intervals, both["fast"][0].coarse_intervals) == (expected, INTERVALS - expected)


@pytest.mark.parametrize("fmi, value", [(3, "true"), (2, "false")])
def test_a_boolean_condition(fmu_dir, tmp_path, fmi, value):
    """``is`` on a Boolean output (the Interpolator's spindle_on, on from the first interval's end): every
    interval fine with ``is = true``, every one coarse with ``is = false``."""
    stepping = table(f'output = "interp.spindle_on", is = {value}')
    both = run_both(load_scenario(write(tmp_path, stepping, fmi), fmu_dir), tmp_path / "runs")
    assert_identical(both)
    result = both["fast"][0]
    on = value == "true"
    assert (result.fine_intervals, result.coarse_intervals) == ((INTERVALS, 0) if on else (0, INTERVALS))
    assert result.fmu_steps == 2 * INTERVALS + 2 * (N_TICKS if on else INTERVALS)


def test_the_run_summary_names_the_fine_share(fmu_dir, tmp_path, capsys):
    code = main(["run", str(SCENARIO), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path), "--no-progress"])
    out = capsys.readouterr().out
    assert code == 0, out
    line = next(line for line in out.splitlines() if line.startswith("variable step: "))
    fine = read_run_info(tmp_path / "slot_entry_variable")["stepping"]["variable_step"]["fine_intervals"]
    assert line == f"variable step: {fine} of {INTERVALS} coarse intervals fine ({100 * fine / INTERVALS:.1f} %)"


# ---- refusals ----


BAD = {
    "coarse step off the grid": ("coarse_step = 1e-3", "coarse_step = 1.000005e-3", "[stepping].coarse_step",
                                 "0.001000005 s is not an integer multiple of the base step 1e-05 s"),
    "no variable instance": ('variable = ["force", "vibration"]', "variable = []", "[stepping].variable",
                             "expected a non-empty list of instance names, got []"),
    "unknown variable instance": ('variable = ["force", "vibration"]', 'variable = ["force", "vibe"]',
                                  "[stepping].variable[1]", "unknown instance 'vibe'; instances: interp, "
                                                            "workpiece, force, vibration"),
    "variable instance twice": ('variable = ["force", "vibration"]', 'variable = ["force", "force"]',
                                "[stepping].variable[1]", "instance 'force' is listed twice"),
    "variable step not dividing": ('coarse_step = 1e-3\nvariable = ["force", "vibration"]',
                                   'coarse_step = 1.5e-3\nvariable = ["interp"]', "[stepping].variable[0]",
                                   "instance 'interp' steps at 0.001 s, which does not divide coarse_step 0.0015 s"),
    "no condition": ("fine_when = [\n  { output = \"workpiece.axial_depth\", above = 0.0 },\n]", "fine_when = []",
                     "[stepping].fine_when", "expected a non-empty list of conditions"),
    "unknown output": ('"workpiece.axial_depth"', '"workpiece.depth"', "[stepping].fine_when[0].output",
                       "unknown variable 'depth' in workpiece (Workpiece); known outputs: axial_depth"),
    "gate not at coarse_step": ('"workpiece.axial_depth"', '"force.Fx"', "[stepping].fine_when[0].output",
                                "instance 'force' steps at 1e-05 s, not at coarse_step 0.001 s"),
    "gate after a variable instance": ('variable = ["force", "vibration"]', 'variable = ["interp", "force"]',
                                       "[stepping].fine_when[0].output",
                                       "instance 'workpiece' does not precede the variable instance 'interp' in "
                                       "the execution order (interp, workpiece, force, vibration)"),
    "gate of type Int32": ('"workpiece.axial_depth", above = 0.0', '"interp.line_number", above = 0.0',
                           "[stepping].fine_when[0].output", "interp.line_number has unsupported type int"),
    "threshold of another dimension": ("above = 0.0", 'above = { value = 2.0, unit = "N" }',
                                       "[stepping].fine_when[0].above", "unit 'N' does not fit workpiece.axial_depth"),
    "is on a Real output": ("above = 0.0", "is = true", "[stepping].fine_when[0].is",
                            "workpiece.axial_depth is Real: give above or below a threshold"),
    "above on a Boolean output": ('"workpiece.axial_depth"', '"interp.spindle_on"',
                                  "[stepping].fine_when[0].above", "interp.spindle_on is Boolean: give is = true"),
    "two senses": ("above = 0.0", "above = 0.0, below = 1.0", "[stepping].fine_when[0]",
                   "give exactly one of above, below (Real outputs) and is (Boolean outputs), got above, below"),
    "hold shorter than the coarse step": ("coarse_step = 1e-3", "coarse_step = 1e-3\nhold = 5e-4",
                                          "[stepping].hold", "0.0005 s is shorter than coarse_step 0.001 s: the "
                                                             "interval in which a condition stops holding"),
    "hold not a time": ("coarse_step = 1e-3", 'coarse_step = 1e-3\nhold = { value = 3, unit = "mm" }',
                        "[stepping].hold", "unit 'mm' is not a time"),
    "hold not a number": ("coarse_step = 1e-3", 'coarse_step = 1e-3\nhold = "long"', "[stepping].hold",
                          "expected a finite number of seconds or { value, unit }, got 'long'"),
}


@pytest.mark.parametrize("case", list(BAD))
def test_a_bad_stepping_table_names_file_and_key(fmu_dir, tmp_path, case):
    old, new, key, message = BAD[case]
    assert old in BASE
    path = write(tmp_path, BASE.replace(old, new))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    assert (info.value.path, info.value.key) == (path, key), str(info.value)
    assert str(info.value).startswith(f"{path}: {key}: ") and message in info.value.detail, str(info.value)


@pytest.mark.parametrize("fmi", [3, 2])
def test_an_fmu_that_cannot_vary_its_step_is_refused(fmu_dir, tmp_path, fmi):
    """A variable instance whose model description says canHandleVariableCommunicationStepSize="false"."""
    name = "ToolVibration" if fmi == 3 else "ToolVibration_fmi2"
    fixed = tmp_path / "FixedStep.fmu"
    with zipfile.ZipFile(fmu_dir / f"{name}.fmu") as source, zipfile.ZipFile(fixed, "w") as target:
        for item in source.infolist():
            data = source.read(item)
            if item.filename == "modelDescription.xml":
                assert b'canHandleVariableCommunicationStepSize="true"' in data
                data = data.replace(b'canHandleVariableCommunicationStepSize="true"',
                                    b'canHandleVariableCommunicationStepSize="false"')
            target.writestr(item, data)
    text = write(tmp_path, fmi=fmi).read_text()
    path = tmp_path / "fixed.toml"
    path.write_text(text.replace(f'fmu = "ToolVibration"{chr(10) + "fmi = 2" if fmi == 2 else ""}',
                                 f'fmu = "FixedStep.fmu"\nfmi = {fmi}'))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    assert info.value.key == "[stepping].variable[1]"
    assert info.value.detail == ("instance 'vibration': FixedStep.fmu declares canHandleVariableCommunicationStepSize="
                                 "\"false\" in its model description, so it cannot take a coarse step")
    path.write_text(path.read_text().replace(STEPPING, ""))
    assert load_scenario(path, fmu_dir).stepping is None  # without [stepping] it runs at its fixed step
