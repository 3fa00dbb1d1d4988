"""The checks of a whole-part scenario's program against its stock and tool, before anything runs: each check with
its message (the program line and the tool named)."""
from __future__ import annotations

import logging
import time
from pathlib import Path

import numpy as np
import pytest

from cases.part_case import MODES, PROGRAM, write_part
from milling_twin.api import simulate
from milling_twin.models.interpolator.tool_table import read_tool_table
from milling_twin.orchestrator.part import checks
from milling_twin.orchestrator.part.model import Stock
from milling_twin.orchestrator.scenario import ScenarioError, load_scenario

REPO_ROOT = Path(__file__).resolve().parents[1]


def _error(tmp_path: Path, fmu_dir: Path, program: str, tools: str | None = None) -> tuple[Path, str]:
    path = write_part(tmp_path, program=program, **({"tools": tools} if tools else {}))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    assert info.value.key == "[part].program"
    return path, str(info.value)


def _warnings(tmp_path: Path, fmu_dir: Path, program: str, tools: str | None = None) -> tuple[str, ...]:
    path = write_part(tmp_path, program=program, **({"tools": tools} if tools else {}))
    return load_scenario(path, fmu_dir).part.warnings


def test_a_tool_the_tool_table_does_not_hold_is_refused(tmp_path: Path, fmu_dir: Path) -> None:
    path, message = _error(tmp_path, fmu_dir, PROGRAM.replace("T1 M6", "T7 M6"))
    assert message == (f"{path}: [part].program: {tmp_path / 'prog.nc'} line 2: \"T7 M6\": a tool of the tool table "
                       f"for T7 (the table has no tool 7)")


TWO_TOOLS = PROGRAM.replace("M5\n", "T2 M6\nG43 H2 Z5\nG0 X-10 Y5\nG1 Z-1 F300\nG1 X60\nG0 Z5\nM5\n").replace(
    "T1 M6\n", "T1 M6\nG43 H1\n")
TWO_LENGTHS = "T1 P1 D10 Z50 ; corner_radius=0.5 flutes=3 helix=30 stick_out=25\nT2 P2 D6 Z42 ; flutes=2 stick_out=20\n"


def test_a_program_cutting_with_two_tools_changes_the_tool_at_its_m6(tmp_path: Path, fmu_dir: Path) -> None:
    """Each tool's geometry, modes and length (the G43 lengths 50 and 42 mm: T2's tip 8 mm nearer the spindle's
    position than T1's) from the communication point the Interpolator shows it."""
    modes = ("[part.tool_modes]\n", "[part.tool_modes]\nT2 = { x = [ { frequency = 2500.0, damping = 0.04, "
             "stiffness = 5.0e7 } ], y = [] }\n")
    scenario = load_scenario(write_part(tmp_path, modes, program=TWO_TOOLS, tools=TWO_LENGTHS), fmu_dir)
    part = scenario.part
    assert [c.tool.number for c in part.cutting_tools] == [1, 2] and part.warnings == ()
    assert [c.length for c in part.cutting_tools] == pytest.approx([0.008, 0.0])
    assert part.program_zero == pytest.approx((0.0, 0.0, 0.042))
    assert part.later_tools[0].modes_x[0].frequency == 2500.0 and part.later_tools[0].modes_y == ()
    assert scenario.instance("workpiece").parameters["tool_length"] == pytest.approx(0.008)
    changes = {c.equals: c.table()["set"] for c in scenario.on_change}
    assert [c.output for c in scenario.on_change] == [scenario.on_change[0].output] * 2
    assert str(scenario.on_change[0].output) == "interp.tool_number"
    assert changes[2]["workpiece.tool_diameter"] == pytest.approx(0.006)
    assert changes[2]["workpiece.tool_length"] == 0.0 and changes[1]["workpiece.tool_length"] == pytest.approx(0.008)
    assert changes[2]["force.n_flutes"] == 2 and changes[2]["vibration.n_modes_y"] == 0
    assert changes[2]["vibration.frequency_x1"] == 2500.0 and changes[1]["force.n_flutes"] == 3


def test_a_tool_without_modes_is_named(tmp_path: Path, fmu_dir: Path) -> None:
    modes = (MODES, "[part.tool_modes]\nT1 = { x = [], y = [] }\n")  # T1's own modes only
    path = write_part(tmp_path, modes, program=TWO_TOOLS)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    assert str(info.value) == (f"{path}: [part.tool_modes]: no modes for T2, which cuts the part: give x and y "
                               f"(every tool's modes), or T2 = {{ x = [...], y = [...] }}")


def test_each_tool_is_checked_against_its_own_flute_length(tmp_path: Path, fmu_dir: Path) -> None:
    deep = TWO_TOOLS.replace("G1 Z-1 F300", "G1 Z-8 F300")
    tools = TWO_LENGTHS.replace("stick_out=20", "stick_out=6")
    assert _warnings(tmp_path, fmu_dir, deep, tools) == (
        f"{tmp_path / 'prog.nc'} line 13: T2 cuts 8.000 mm below the stock top, deeper than its flute length "
        f"6.000 mm",)


def test_forcenet_takes_one_tool(tmp_path: Path, fmu_dir: Path) -> None:
    path = write_part(tmp_path, ("[part]\n", "[part]\nforce_model = \"ForceNet\"\n"), program=TWO_TOOLS)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    assert str(info.value) == (f"{path}: [part].force_model: \"ForceNet\" learned the forces of one tool; the "
                               f"program cuts with 2 tools (T1, T2): use \"CuttingForce\", or one part per tool")


def test_a_second_tool_that_never_reaches_the_stock_is_accepted(tmp_path: Path, fmu_dir: Path) -> None:
    program = PROGRAM.replace("M5\n", "T2 M6\nG0 X-10 Y5\nG1 Z1 F300\nG1 X60\nG0 Z5\nM5\n")  # 1 mm above the top
    assert _warnings(tmp_path, fmu_dir, program) == ()


def test_cutting_with_no_tool_selected_is_refused_among_several(tmp_path: Path, fmu_dir: Path) -> None:
    path, message = _error(tmp_path, fmu_dir, PROGRAM.replace("T1 M6\n", ""))
    assert message == (f"{path}: [part].program: {tmp_path / 'prog.nc'} line 5: cuts the stock with no tool selected "
                       f"(no T.. M6 before it) while the tool table holds 2 tools: select the tool with T<n> M6")


def test_no_tool_selected_means_the_only_tool_of_the_table(tmp_path: Path, fmu_dir: Path) -> None:
    path = write_part(tmp_path, program=PROGRAM.replace("T1 M6\n", ""),
                      tools="T4 P4 D8 ; flutes=2 helix=30 stick_out=20\n")
    scenario = load_scenario(path, fmu_dir)
    assert scenario.part.tool.number == 4 and scenario.instance("workpiece").parameters["tool_diameter"] == 0.008


def test_a_stock_the_program_never_touches_warns(tmp_path: Path, fmu_dir: Path,
                                                 caplog: pytest.LogCaptureFixture) -> None:
    with caplog.at_level(logging.WARNING, logger="milling_twin.part"):
        warnings = _warnings(tmp_path, fmu_dir, PROGRAM.replace("Y10 Z5", "Y40 Z5"))  # 10 mm beside the block
    assert warnings == (f"{tmp_path / 'prog.nc'}: no feed move reaches the stock (x 0.000 .. 50.000, y 0.000 .. "
                        f"20.000, z -10.000 .. 0.000 mm): the program never cuts it",)
    assert warnings[0] in caplog.messages


def test_a_plunge_below_the_stock_bottom_is_refused(tmp_path: Path, fmu_dir: Path) -> None:
    path, message = _error(tmp_path, fmu_dir, PROGRAM.replace("G1 X60 F600", "G1 X20 F600\nG1 Z-12.5"))
    assert message == (f"{path}: [part].program: {tmp_path / 'prog.nc'} line 7: the tool tip goes down to "
                       f"z = -12.500 mm over the stock, 2.500 mm below the stock bottom (z = -10.000 mm)")


def test_a_cut_deeper_than_the_flute_length_warns(tmp_path: Path, fmu_dir: Path) -> None:
    program = PROGRAM.replace("G1 X60 F600", "G1 X60 F600\nG1 Z-8\nG1 X-10")
    warnings = _warnings(tmp_path, fmu_dir, program, tools="T1 P1 D10 ; flutes=3 helix=30 stick_out=6\n")
    assert warnings == (f"{tmp_path / 'prog.nc'} line 8: T1 cuts 8.000 mm below the stock top, deeper than its flute "
                        f"length 6.000 mm",)  # the plunge of line 7 lies beside the block


def test_a_feed_move_in_the_stock_with_the_spindle_stopped_warns(tmp_path: Path, fmu_dir: Path) -> None:
    warnings = _warnings(tmp_path, fmu_dir, PROGRAM.replace("S6000 M3\n", ""))
    assert warnings == (f"{tmp_path / 'prog.nc'} line 5: a feed move in the stock with the spindle stopped",)


def test_a_rapid_into_stock_no_feed_move_has_cut_warns(tmp_path: Path, fmu_dir: Path) -> None:
    """The G0 that plunges 1 mm beside the slot (at y 3: the slot, cut at y 10 with the 10 mm tool, reaches down to
    y 5) is a collision, named with its line and tool before anything runs; the slot's own G0 retract, and a G0 down
    into the slot after it is cut, are not."""
    collision = PROGRAM.replace("G0 Z5\nM5\n", "G0 Z5\nG0 X30 Y3\nG0 Z-1\nG0 Z5\nM5\n")
    warnings = _warnings(tmp_path / "collision", fmu_dir, collision)
    rapids = [w for w in warnings if "rapid move (G0)" in w]
    assert rapids == [f"{tmp_path / 'collision' / 'prog.nc'} line 9: the rapid move (G0) with T1 goes 1.000 mm into "
                      "the stock where no earlier feed move has cut (from x y z = 30.000 3.000 -0.500 mm): on the "
                      "machine a collision"], warnings
    into_the_slot = PROGRAM.replace("G0 Z5\nM5\n", "G0 Z5\nG0 X30 Y8\nG0 Z-1.5\nG0 Z5\nM5\n")
    assert not [w for w in _warnings(tmp_path / "slot", fmu_dir, into_the_slot) if "rapid" in w]
    before_the_slot = PROGRAM.replace("G0 X-10 Y10 Z5\n", "G0 X30 Y10 Z5\nG0 Z-1\nG0 Z5\nG0 X-10 Y10\n")
    assert [w for w in _warnings(tmp_path / "before", fmu_dir, before_the_slot) if "rapid" in w]
    assert not [w for w in _warnings(tmp_path / "clean", fmu_dir, PROGRAM) if "rapid" in w]


def test_arcs_are_followed_along_their_sweep(tmp_path: Path, fmu_dir: Path) -> None:
    # a half circle from the left of the block, bulging into it: only its middle is over the stock
    program = PROGRAM.replace("G0 X-10 Y10 Z5\nG1 Z-2 F300\nG1 X60 F600",
                              "G0 X-10 Y-20 Z5\nG1 Z-12 F300\nG3 X-10 Y40 I0 J30 F600")
    path, message = _error(tmp_path, fmu_dir, program)
    assert message.endswith("line 6: the tool tip goes down to z = -12.000 mm over the stock, 2.000 mm below the "
                            "stock bottom (z = -10.000 mm)")
    assert _warnings(tmp_path / "cw", fmu_dir, program.replace("G3", "G2").replace("Z-12", "Z-5")) == (
        f"{tmp_path / 'cw' / 'prog.nc'}: no feed move reaches the stock (x 0.000 .. 50.000, y 0.000 .. 20.000, "
        f"z -10.000 .. 0.000 mm): the program never cuts it",)  # the clockwise arc bulges away from the block


def test_the_stock_is_in_program_coordinates_with_the_tool_length_and_the_work_offset(tmp_path: Path,
                                                                                      fmu_dir: Path) -> None:
    """G43 H1 puts the spindle 50 mm (the tool length) above the programmed tip and G55 shifts the work zero: the
    checks and the Workpiece see the tip in the program's coordinates, and the run cuts the 2 mm slot."""
    program = PROGRAM.replace("G0 X-10 Y10 Z5", "G55\nG0 X-10 Y10\nG43 Z5 H1")
    edits = [("[part.machine]\n", '[part.machine]\ng55_x = 0.1\ng55_z = { value = -300, unit = "mm" }\n'),
             ("start_z = { value = 5, unit = \"mm\" }", "start_z = { value = -245, unit = \"mm\" }"),
             ("start_x = { value = -10, unit = \"mm\" }", "start_x = { value = 90, unit = \"mm\" }"),
             ('description = "one slot through a small block"', "stop_time = 3.0")]
    scenario = load_scenario(write_part(tmp_path, *edits, program=program), fmu_dir)
    assert scenario.part.warnings == ()
    frame = simulate(scenario).frame
    cutting = frame[(frame["time"] > 1.0) & (frame["interp.x_program"] > 0.003)]
    assert len(cutting) > 1000  # 0.3 s of the slot at 1e-4 s
    assert np.allclose(cutting["workpiece.axial_depth"], 0.002, atol=1e-4)
    assert np.allclose(cutting["interp.z"], -0.3 + 0.05 - 0.002)  # machine z: offset + tool length + tip
    assert cutting["force.Fy"].abs().mean() > 10.0


def test_the_checks_take_milliseconds_on_the_largest_program(tmp_path: Path) -> None:
    """The reconstructed UMich program (118 moves, the largest committed) with a 6 mm tool over its pocket."""
    tools = read_tool_table(REPO_ROOT / "scenarios" / "programs" / "corpus" / "tool.tbl")
    program = REPO_ROOT / "scenarios" / "programs" / "umich_01.nc"
    stock = Stock((0.13, 0.06, 0.0), (0.04, 0.05, 0.030), 5e-4)
    start = time.perf_counter()
    path = checks.feed_path(checks.parse(program, "fanuc", (tools[3],), {}))

    def fail(message: str) -> None:
        raise AssertionError(message)

    cutting = checks.cutting_tools(path, (tools[3],), stock, fail)
    warnings = checks.check_part(path, (tools[3],), [(cutting[0], 0.035)], stock, fail)
    elapsed = time.perf_counter() - start
    assert [t.number for t in cutting] == [4] and warnings == [] and len(path.points) > 1000
    assert elapsed < 0.5, elapsed


def test_cutting_with_two_program_zeros_is_refused(tmp_path: Path, fmu_dir: Path) -> None:
    program = PROGRAM.replace("M5\n", "G55\nG0 X-10 Y5\nG1 Z-1 F300\nG1 X60\nG0 Z5\nM5\n")
    path = write_part(tmp_path, ("[part.machine]\n", "[part.machine]\ng55_x = 0.1\n"), program=program)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    assert str(info.value) == (
        f"{path}: [part].program: {tmp_path / 'prog.nc'} lines 6 and 11: the program cuts the stock with two "
        f"positions of its zero, x y z = 0.000 0.000 0.000 and 100.000 0.000 0.000 mm in machine coordinates (work "
        f"offset G54..G59, G52, G43 tool length): the stock is placed with one")


def test_a_program_without_a_cut_has_the_tool_it_selects_or_none(tmp_path: Path, fmu_dir: Path) -> None:
    rapids = "G21 G90\nT2 M6\nS6000 M3\nG0 X-10 Y10 Z5\nG0 X60\nM30\n"
    path = write_part(tmp_path / "t2", program=rapids)
    scenario = load_scenario(path, fmu_dir)
    assert scenario.part.tool.number == 2
    assert scenario.part.warnings == (f"{tmp_path / 't2' / 'prog.nc'}: no feed move reaches the stock (x 0.000 .. "
                                      f"50.000, y 0.000 .. 20.000, z -10.000 .. 0.000 mm): the program never cuts it",)
    path = write_part(tmp_path / "none", program=rapids.replace("T2 M6\n", ""))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    assert str(info.value) == (f"{path}: [part].program: {tmp_path / 'none' / 'prog.nc'}: no feed move reaches the "
                               f"stock and the program selects no tool (T.. M6), while the tool table holds 2 tools: "
                               f"the part's tool is unknown")
