"""The feed optimizer (``milling-twin optimize``, orchestrator/optimize/): the schedule's rules on made-up runs, the
``[optimize]`` section's checks, and a whole optimization of the tiny part (a slot) through the twin."""
from __future__ import annotations

import json
import re
from pathlib import Path

import pandas as pd
import pytest

import milling_twin
from cases.part_case import write_part
from milling_twin.cli import main
from milling_twin.orchestrator.optimize import schedule
from milling_twin.orchestrator.optimize.schedule import LineRun, ToolLimits, next_factors
from milling_twin.orchestrator.scenario import ScenarioError

MM_MIN = 1.0 / 60000.0


def run(line: int, factor: float, force: float, *, cuts: bool = True, chatter: bool = False, tool: int = 1,
        duration: float = 1.0, spindle: float = 628.3185307179587) -> LineRun:
    """A line of a run: 600 mm/min at factor 1, 6000 rpm."""
    return LineRun(line, tool, factor, 600 * MM_MIN * factor, spindle, duration / factor, cuts,
                   {"force": force, "torque": 0.0, "power": 0.0, "deflection": 0.0}, chatter)


LIMITS = ToolLimits({"force": 150.0}, 0.0, 1e-3, 10000 * MM_MIN, 3)  # fz up to 1 mm: the force limit decides
FEEDS = {10: 600 * MM_MIN, 11: 600 * MM_MIN}


def linear_force(factor: float) -> float:
    return 40.0 + 80.0 * factor   # the mechanistic force at a fixed engagement: edge + shear term


def test_a_line_that_cuts_reaches_its_force_limit_in_two_steps_of_a_linear_force() -> None:
    history = [{10: run(10, 1.0, linear_force(1.0))}]
    first = next_factors(history, FEEDS, lambda tool: LIMITS, "keep")[10]
    assert first == pytest.approx(150.0 / 120.0)  # proportional from one run: short of the limit
    assert linear_force(first) < 150.0
    history.append({10: run(10, first, linear_force(first))})
    second = next_factors(history, FEEDS, lambda tool: LIMITS, "keep")[10]
    assert linear_force(second) == pytest.approx(150.0)


def test_the_feed_per_tooth_range_and_the_machine_feed_bound_the_factor() -> None:
    history = [{10: run(10, 1.0, 10.0)}]  # far below the force limit
    per_tooth = ToolLimits({"force": 150.0}, 0.0, 0.05e-3, 10000 * MM_MIN, 3)  # 0.05 mm: 900 mm/min at 6000 rpm
    assert next_factors(history, FEEDS, lambda tool: per_tooth, "keep")[10] == pytest.approx(1.5)
    machine = ToolLimits({"force": 150.0}, 0.0, 1e-3, 700 * MM_MIN, 3)
    assert next_factors(history, FEEDS, lambda tool: machine, "keep")[10] == pytest.approx(700 / 600)
    thin = ToolLimits({"force": 150.0}, 0.04e-3, 1e-3, 10000 * MM_MIN, 3)  # at least 0.04 mm: 720 mm/min
    low = [{10: run(10, 1.0, 100.0)}]  # objective force at half the limit: 0.75, raised to the thinnest chip
    assert next_factors(low, FEEDS, lambda tool: thin, "keep", force_scale=0.5)[10] == pytest.approx(1.2)
    over = [{10: run(10, 1.0, 300.0)}]  # the force limit itself wins over the thinnest chip
    assert next_factors(over, FEEDS, lambda tool: thin, "keep", force_scale=0.5)[10] == pytest.approx(0.5)


def test_air_moves_plunges_and_chatter() -> None:
    history = [{10: run(10, 1.0, 0.0, cuts=False), 11: run(11, 1.0, 100.0)}]
    per_tooth = ToolLimits({"force": 150.0}, 0.0, 0.05e-3, 10000 * MM_MIN, 3)
    assert next_factors(history, FEEDS, lambda tool: per_tooth, "keep")[10] == 1.0
    assert next_factors(history, FEEDS, lambda tool: per_tooth, "fastest")[10] == pytest.approx(1.5)
    assert next_factors(history, FEEDS, lambda tool: LIMITS, "keep", plunges={11})[11] == 1.0
    history.append({10: run(10, 1.5, 0.0, cuts=False), 11: run(11, 1.5, 140.0, chatter=True)})
    assert next_factors(history, FEEDS, lambda tool: LIMITS, "keep")[11] == 1.0  # the fastest without chatter


def test_a_value_the_feed_cannot_bring_under_its_limit_falls_in_bounded_steps() -> None:
    """A force of 170 N at factor 1 and 160 N at 0.5 (an edge force, a forced vibration: 150 N at no feed): the
    secant meets the 150 N limit at no positive feed. The next factor is the proportional step, not ~0; and a
    factor never falls more than GROWTH times from one run to the next."""
    history = [{10: run(10, 1.0, 170.0)}, {10: run(10, 0.5, 160.0)}]
    factor = next_factors(history, FEEDS, lambda tool: LIMITS, "keep")[10]
    assert factor == pytest.approx(0.5 * 150.0 / 160.0)
    steep = [{10: run(10, 1.0, 1500.0)}]   # ten times the limit: proportional would be 0.1, a fall of 10
    assert next_factors(steep, FEEDS, lambda tool: LIMITS, "keep")[10] == pytest.approx(1.0 / schedule.GROWTH)


def test_a_tool_the_part_does_not_cut_with_or_a_stopped_spindle_keeps_its_feed() -> None:
    history = [{10: run(10, 1.0, 50.0, tool=7), 11: run(11, 1.0, 50.0, spindle=0.0)}]
    factors = next_factors(history, FEEDS, lambda tool: LIMITS if tool == 1 else None, "fastest")
    assert factors == {10: 1.0, 11: 1.0}


def test_the_force_objective_scale_gives_the_target_time() -> None:
    """Two lines of 1 s each; the first at its limit, the second far below: the second pays for the first."""
    history = [{10: run(10, 1.0, 150.0), 11: run(11, 1.0, 50.0)}]
    per_tooth = ToolLimits({"force": 150.0}, 0.0, 0.2e-3, 10000 * MM_MIN, 3)
    scale = schedule.scale_for_time(history, FEEDS, lambda tool: per_tooth, "keep", 2.0, 2.0)
    factors = next_factors(history, FEEDS, lambda tool: per_tooth, "keep", scale)
    assert scale < 1.0 and factors[10] == pytest.approx(scale, rel=1e-3)
    assert 2.0 + schedule.predicted_time(history, factors) == pytest.approx(2.0, abs=2e-3)


# ---- [optimize] ----

@pytest.mark.parametrize("section,key,message", [
    ("[optimize]\nobjectiv = \"time\"\n", "[optimize].objectiv", "unknown key 'objectiv'"),
    ("[optimize]\nobjective = \"cost\"\n", "[optimize].objective", "'cost' is not one of time, force"),
    ("[optimize.limits]\nfeed_per_tooth = { value = [0.1, 0.05], unit = \"mm\" }\n",
     "[optimize.limits].feed_per_tooth", "expected 0 <= min < max"),
    ("[optimize.limits]\nforce = { value = 100, unit = \"N.m\" }\n", "[optimize.limits].force", "unit 'N.m'"),
    ("[optimize.limits.T2]\nspeed = 3\n", "[optimize.limits.T2].speed", "unknown key 'speed'"),
    ("[optimize]\nspeed_from = \"lobes\"\n", "[optimize].speed_from", "'lobes' is not one of simulated, zero-order"),
    ("[optimize]\nsub_blocks = 1\n", "[optimize].sub_blocks", "expected true or false, got 1"),
    ("[optimize]\nsub_block_length = { value = -2, unit = \"mm\" }\n", "[optimize].sub_block_length", "must be > 0"),
], ids=["unknown-key", "objective", "feed-per-tooth-range", "force-unit", "tool-unknown-key", "speed-from",
        "sub-blocks", "sub-block-length"])
def test_a_bad_optimize_section_names_the_file_and_key(tmp_path: Path, fmu_dir: Path, section: str, key: str,
                                                       message: str) -> None:
    part = write_part(tmp_path / "part", ("[part.spindle]", section + "[part.spindle]"))
    with pytest.raises(ScenarioError) as caught:
        milling_twin.optimize(part, fmu_dir=fmu_dir, out=tmp_path / "runs")
    assert str(caught.value).startswith(f"{part}: {key}: ") and message in str(caught.value), caught.value
    assert not (tmp_path / "runs").exists()


def test_a_scenario_without_part_is_refused(tmp_path: Path, fmu_dir: Path, capsys) -> None:
    scenario = Path(__file__).resolve().parents[1] / "scenarios" / "chatter.toml"
    assert main(["optimize", str(scenario), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path)]) == 2
    assert f"{scenario}: [part]: missing: the optimizer takes a whole-part scenario" in capsys.readouterr().err


# ---- a whole optimization ----

def test_the_tiny_part_is_cut_faster_at_its_force_limit(tmp_path: Path, fmu_dir: Path) -> None:
    """The slot at 600 mm/min has its largest force near 131 N; with a limit of 150 N the optimizer raises the
    feed until the re-simulated slot stays within 1 % of it, changing only F words (one feed per line: the
    sub-blocks are tests/test_optimize_sub_blocks.py's)."""
    part = write_part(tmp_path / "part", ("[part.spindle]", '[optimize]\nmax_iterations = 5\n[optimize.limits]\n'
                                          'force = { value = 150, unit = "N" }\n'
                                          'feed_per_tooth = { value = [0.01, 0.3], unit = "mm" }\n[part.spindle]'))
    lines: list[str] = []
    result = milling_twin.optimize(part, fmu_dir=fmu_dir, out=tmp_path / "runs", echo=lines.append,
                                   sub_blocks=False)
    folder = tmp_path / "runs" / "optimize" / "tiny_part"
    original, best = result.original, result.best
    assert best.number > 0 and best.feasible
    assert max(best.peak_force.values()) <= 150.0 * 1.01
    assert best.cycle_time < 0.8 * original.cycle_time, (original.cycle_time, best.cycle_time)
    assert len(lines) == len(result.iterations) and lines[0].startswith("iteration 0: cycle ")
    old = (tmp_path / "part" / "prog.nc").read_text().splitlines()
    new = result.program.read_text().splitlines()
    assert result.program == folder / "prog_optimized.nc" and len(old) == len(new)
    changed = [(a, b) for a, b in zip(old, new) if a != b]
    assert changed and all(re.sub(r"F[\d.]+", "", a) == re.sub(r"F[\d.]+", "", b) for a, b in changed)
    doc = json.loads((folder / "optimize.json").read_text())
    assert [it["iteration"] for it in doc["iterations"]] == [it.number for it in result.iterations]
    assert doc["limits"]["1"]["force"] == 150.0 and doc["units"]["force"] == "N"
    page = result.report.read_text()
    assert page.rstrip().endswith("</html>") and "data:image/png;base64," in page and "<pre class='diff'>" in page
    table = pd.read_csv(folder / "blocks_before_after.csv")
    slot = table[table["line"] == 6].iloc[0]
    assert slot["F before [mm/min]"] == pytest.approx(600.0) and slot["F after [mm/min]"] > 700.0
    assert slot["force max after [N]"] <= 151.5


def test_a_killed_optimization_leaves_its_iterations_readable(tmp_path: Path, fmu_dir: Path) -> None:
    """SIGKILL once the first iterations are written: optimize.json (written atomically after each run) still
    loads and lists them, each with its program and run folder."""
    import os
    import signal
    import subprocess
    import sys
    import time

    part = write_part(tmp_path / "part", ("[part.spindle]", '[optimize]\nmax_iterations = 6\n[optimize.limits]\n'
                                          'force = { value = 150, unit = "N" }\n[part.spindle]'))
    record = tmp_path / "runs" / "optimize" / "tiny_part" / "optimize.json"
    proc = subprocess.Popen([sys.executable, "-m", "milling_twin", "optimize", str(part), "--fmu-dir", str(fmu_dir),
                             "--out", str(tmp_path / "runs"), "--no-progress"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while time.monotonic() < deadline and proc.poll() is None:
            if record.is_file() and len(json.loads(record.read_text())["iterations"]) >= 2:
                break
            time.sleep(0.05)
        assert proc.poll() is None, "the optimization ended before it could be killed"
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    doc = json.loads(record.read_text())
    assert len(doc["iterations"]) >= 2 and doc["iterations"][0]["iteration"] == 0
    for it in doc["iterations"]:
        assert Path(it["program"]).is_file() and (Path(it["run_dir"]) / "blocks.parquet").is_file()


@pytest.mark.parametrize("speed_from", ["simulated", "zero-order"])
def test_a_chattering_tool_gets_the_speed_of_a_stable_pocket(tmp_path: Path, fmu_dir: Path, speed_from: str) -> None:
    """The tiny part 0.1 mm deep on the flexible tool of scenarios/chatter.toml (922 Hz, 1.1 %, 1.34e6 N/m): at
    5850 rpm with 3 flutes, below the lobe at 6150 rpm (a zero-order limit of 0.088 mm), the slot chatters. The
    optimizer moves S to the nearest speed stable at 1.25 x the depth: in the tool's simulated map (a study of its
    force/vibration loop whose files stay beside the optimization), or by the zero-order limit; in the
    re-simulation the slot no longer chatters."""
    from cases.part_case import MODES, PROGRAM

    mode = "[ { frequency = 922.0, damping = 0.011, stiffness = 1.34e6 } ]"
    part = write_part(tmp_path / "part", (MODES, f"[part.tool_modes]\nx = {mode}\ny = {mode}\n"),
                      ("[part.spindle]", f'[optimize]\nmax_iterations = 2\nspeed_from = "{speed_from}"\n'
                                         f'[part.spindle]'),
                      program=PROGRAM.replace("G1 Z-2 F300", "G1 Z-0.1 F300").replace("S6000", "S5850"))
    result = milling_twin.optimize(part, fmu_dir=fmu_dir, out=tmp_path / "runs")
    choice = result.speeds[1]
    assert choice.programmed == pytest.approx(5850.0) and choice.limit_programmed < 0.1e-3
    assert 0.7 * 5850 <= choice.chosen <= 1.3 * 5850 and abs(choice.chosen - 5850) >= 50
    assert choice.source == speed_from and choice.note == ""
    folder = tmp_path / "runs" / "optimize" / "tiny_part"
    if speed_from == "simulated":
        assert choice.map is not None and choice.map.depth == pytest.approx(1.25 * 0.1e-3)
        assert choice.stable_chosen and choice.chip_chosen <= 0.1
        assert not dict(zip(choice.map.speeds, choice.map.stable))[5850.0]
        assert len(choice.map.speeds) >= 30 and choice.study == folder / "speeds" / "T1_speeds_fine.toml"
        assert choice.study.is_file() and (folder / "speeds" / "T1_speeds.toml").is_file()
    else:
        assert choice.limit_chosen >= 1.25 * 0.1e-3 and choice.map is None and choice.stable_chosen is None
    new = result.program.read_text()
    assert f"S{choice.chosen:.0f} M3" in new and "S5850" not in new
    table = pd.read_csv(folder / "blocks_before_after.csv")
    slot = table[table["line"] == 6]
    assert bool(slot["chatter before"].iloc[0]) and not slot["chatter after"].astype(bool).any()
    assert result.best.feasible and result.best.number >= 1
    doc = json.loads((folder / "optimize.json").read_text())
    assert doc["spindle_speeds"]["1"]["chosen"] == choice.chosen and doc["spindle_speeds"]["1"]["source"] == speed_from
    assert "<h2>Spindle speeds</h2>" in result.report.read_text()


def test_a_part_cut_by_one_tool_takes_its_limits_also_where_the_program_selects_none() -> None:
    """UMich run 01's program selects no tool (T0, as the process report's tool column shows): its one cutting tool
    is the tool of every line, so the tool's limits apply (before, no line had limits and nothing changed)."""
    from types import SimpleNamespace

    from milling_twin.orchestrator.optimize.run import tool_numbers

    one = SimpleNamespace(cutting_tools=(SimpleNamespace(tool=SimpleNamespace(number=1)),))
    two = SimpleNamespace(cutting_tools=(SimpleNamespace(tool=SimpleNamespace(number=1)),
                                         SimpleNamespace(tool=SimpleNamespace(number=2))))
    assert tool_numbers(one)(0) == 1 and tool_numbers(one)(1) == 1
    assert tool_numbers(two)(0) == 0 and tool_numbers(two)(2) == 2
    blocks = pd.DataFrame({"line": [6], "tool": [0], "feed_programmed": [0.01], "spindle_speed": [628.3],
                           "duration": [1.0], "in_cut_fraction": [1.0], "chatter": [False], "force_max": [100.0],
                           "torque_max": [0.5], "spindle_power_max": [900.0], "deflection_max": [1e-5]})
    runs = schedule.line_runs(blocks, {6: 0.01}, [6], tool_numbers(one))
    assert runs[6].tool == 1 and runs[6].metrics["force"] == 100.0


def test_a_program_whose_chatter_breaks_the_run_gets_a_stable_speed(tmp_path: Path, fmu_dir: Path) -> None:
    """At 5400 rpm, between two lobes, the tiny part's slot on the flexible tool chatters until the tool's
    displacement leaves the FMUs' range and the run fails: simulate raises with the blocks up to there (a partial
    process report naming the failure), and the optimizer takes the speed of the simulated map's pocket from them;
    the optimized program runs to its end without chatter."""
    from cases.part_case import MODES, PROGRAM
    from milling_twin.orchestrator.master import SimulationError

    mode = "[ { frequency = 922.0, damping = 0.011, stiffness = 1.34e6 } ]"
    part = write_part(tmp_path / "part", (MODES, f"[part.tool_modes]\nx = {mode}\ny = {mode}\n"),
                      ("[part.spindle]", "[optimize]\nmax_iterations = 2\n[part.spindle]"),
                      program=PROGRAM.replace("G1 Z-2 F300", "G1 Z-0.1 F300").replace("S6000", "S5400"))
    with pytest.raises(SimulationError, match="out of its allowed range") as failed:
        milling_twin.simulate(part, fmu_dir=fmu_dir, out=tmp_path / "plain")
    report = failed.value.process_report
    assert report is not None and failed.value.run_dir == tmp_path / "plain" / "tiny_part"
    blocks = pd.read_parquet(report.blocks_parquet)
    assert 6 in set(blocks["line"]) and "the run failed" in report.html.read_text()
    result = milling_twin.optimize(part, fmu_dir=fmu_dir, out=tmp_path / "runs")
    assert result.original.status.startswith("failed") and not result.original.feasible
    choice = result.speeds[1]
    assert choice.stable_chosen and abs(choice.chosen - 5400.0) > 200 and choice.note == ""
    assert result.best.number >= 1 and result.best.status == "completed" and result.best.feasible
    table = pd.read_csv(result.folder / "blocks_before_after.csv")
    assert not table[table["line"] == 6]["chatter after"].astype(bool).any()


def test_a_stable_speed_that_the_program_cannot_hold_keeps_s_with_a_note(tmp_path: Path, fmu_dir: Path) -> None:
    """The chattering slot of the test above, its feeds given per revolution (G95): a new S would change every
    feed with it, which the move-by-move check refuses. The optimizer keeps S, says why, and still schedules the
    feeds."""
    from cases.part_case import MODES, PROGRAM

    mode = "[ { frequency = 922.0, damping = 0.011, stiffness = 1.34e6 } ]"
    program = PROGRAM.replace("G1 Z-2 F300", "G95 G1 Z-0.1 F0.05").replace("G1 X60 F600", "G1 X60 F0.1") \
        .replace("S6000", "S5850")
    part = write_part(tmp_path / "part", (MODES, f"[part.tool_modes]\nx = {mode}\ny = {mode}\n"),
                      ("[part.spindle]", '[optimize]\nmax_iterations = 1\nspeed_from = "zero-order"\n'
                                         '[part.spindle]'), program=program)
    result = milling_twin.optimize(part, fmu_dir=fmu_dir, out=tmp_path / "runs")
    choice = result.speeds[1]
    assert choice.chosen == choice.programmed == pytest.approx(5850.0)
    assert "cannot be written into this program" in choice.note and "S kept" in choice.note
    assert any("S kept" in note for note in result.notes)
    assert "S5850" in result.program.read_text()
