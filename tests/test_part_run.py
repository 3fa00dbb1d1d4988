"""A whole-part scenario run as a user runs it (``milling-twin run PART.toml``): the Workpiece writes the final
Z-map into the run folder, the process report follows the run, the summary gives its headline; and the variable
step agrees with the all-fine-step run of the same part (the benchmark's figures in miniature)."""
from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd

import milling_twin
from cases.part_case import PROGRAM, write_part
from milling_twin.models.workpiece import read_zmap


def test_run_writes_the_surface_and_the_process_report(tmp_path: Path, fmu_dir: Path) -> None:
    part = write_part(tmp_path / "part")
    proc = subprocess.run([sys.executable, "-m", "milling_twin", "run", str(part), "--fmu-dir", str(fmu_dir),
                           "--out", str(tmp_path / "runs"), "--no-progress"], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    run_dir = tmp_path / "runs" / "tiny_part"
    for name in ("final_zmap.asc", "part.stl", "process_report.html", "process_report.json", "blocks.csv",
                 "blocks.parquet", "run.json"):
        assert (run_dir / name).is_file(), name
    assert "variable step: " in proc.stdout
    headline = next(line for line in proc.stdout.splitlines() if line.startswith("part: machining"))
    assert " 0 in chatter" in headline
    assert f"process report: {run_dir / 'process_report.html'}, surface: {run_dir / 'part.stl'}" in proc.stdout
    x, y, heights = read_zmap(run_dir / "final_zmap.asc")
    assert heights.shape == (y.size, x.size) and heights.min() < heights.max()   # the slot is in it


def test_a_plunge_into_the_stock_is_marked_and_named_in_the_report(tmp_path: Path, fmu_dir: Path) -> None:
    """The tiny part's slot entered by a plunge at x = 25 mm: that line cuts descending (slope 1), and the run says
    that its force leaves out the end cutting; the slot after it is no plunge."""
    program = PROGRAM.replace("G0 X-10 Y10 Z5", "G0 X25 Y10 Z5")
    part = write_part(tmp_path / "part", program=program)
    proc = subprocess.run([sys.executable, "-m", "milling_twin", "run", str(part), "--fmu-dir", str(fmu_dir),
                           "--out", str(tmp_path / "runs"), "--no-progress"], capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, proc.stderr[-3000:]
    blocks = pd.read_csv(tmp_path / "runs" / "tiny_part" / "blocks.csv").set_index("line")
    assert blocks.loc[5, "plunge"] and blocks.loc[5, "removed_volume [cm3]"] > 0.1   # pi 5^2 x 2 mm: 0.157 cm3
    assert not blocks.loc[6, "plunge"] and not blocks.loc[4, "plunge"]
    assert ("part warning: plunging or steeply ramping while cutting (descending more than 0.25 per length of "
            "path), line 5: the force models have flank edges only") in proc.stdout + proc.stderr


def test_variable_step_agrees_with_the_all_fine_run(tmp_path: Path, fmu_dir: Path) -> None:
    """The slot of the tiny part: in material the force, torque and deflection of the variable-step run equal the
    all-fine run's to far below 1 % of their RMS; the Workpiece's outputs are identical; fewer doSteps."""
    scenario = milling_twin.load_scenario(write_part(tmp_path / "part"), fmu_dir)
    variable = milling_twin.simulate(scenario, out=tmp_path / "runs")
    fine = milling_twin.simulate(dataclasses.replace(scenario, stepping=None, name="tiny_part_all_fine"),
                                 out=tmp_path / "runs")
    a, b = variable.frame, fine.frame
    assert variable.run.coarse_intervals > 0 and variable.run.fmu_steps < fine.run.fmu_steps
    cut = b["workpiece.axial_depth"].to_numpy() > 0.0
    assert cut.sum() > 1000
    for column in ("force.Fx", "force.Fy", "force.torque", "vibration.tip_displacement_x",
                   "vibration.tip_displacement_y"):
        x, y = a[column].to_numpy()[cut], b[column].to_numpy()[cut]
        assert np.sqrt(np.mean((x - y) ** 2)) < 0.01 * np.sqrt(np.mean(y ** 2)), column
    for column in [c for c in b.columns if c.startswith("workpiece.") or c.startswith("interp.")]:
        assert np.array_equal(a[column].to_numpy(), b[column].to_numpy()), column
    assert variable.process_report is not None
    assert variable.process_report.removed_volume_zmap is not None
    assert abs(variable.process_report.removed_volume_zmap - variable.process_report.removed_volume) \
        <= 1e-9 * variable.process_report.removed_volume


def test_a_two_tool_part_cuts_each_slot_with_its_tool(tmp_path: Path, fmu_dir: Path) -> None:
    """T1 (D10, corner 0.5 mm, G43 50 mm) slots 2 mm deep through the 50 mm block at y 10; T2 (D6, G43 42 mm) 1 mm
    deep at y 5, half in T1's slot. The Workpiece removes T1's slot (50 x 10 x 2 mm less the corner fillets) and
    T2's new 3 mm (50 x 3 x 1): 1144.6 mm3; with T1's diameter it would be 1244.6, with T1's length nothing or a
    plunge 8 mm deep. The process report gives each block its own tool."""
    from test_part_checks import TWO_LENGTHS, TWO_TOOLS

    result = milling_twin.simulate(milling_twin.load_scenario(
        write_part(tmp_path / "part", program=TWO_TOOLS, tools=TWO_LENGTHS), fmu_dir), out=tmp_path / "runs")
    assert [(e.output, e.value) for e in result.run.events] == [("interp.tool_number", 1), ("interp.tool_number", 2)]
    frame = result.frame
    fillets = 2 * (0.5 ** 2 - np.pi * 0.5 ** 2 / 4) * 50           # mm3: T1's corner radius along the slot
    expected = (50 * 10 * 2 - fillets + 50 * 3 * 1) * 1e-9
    removed = frame["workpiece.removed_volume"].to_numpy()[-1]
    assert abs(removed - expected) < 0.01 * expected, (removed, expected)
    second = frame[(frame["interp.line_number"] == 13) & (frame["interp.x_program"].between(0.01, 0.04))]
    assert len(second) > 100 and np.allclose(second["workpiece.axial_depth"], 0.001, atol=1e-4)
    assert np.allclose(second["workpiece.radial_depth"], 0.003, atol=6e-4)  # the 3 mm T1 left
    blocks = result.process_report
    assert blocks is not None
    table = pd.read_parquet(blocks.blocks_parquet)
    assert set(table.loc[table["axial_depth_max"] > 0, "tool"]) == {1, 2}
    # each tool's straight slot gets its volume check with its own diameter (not only the last tool's blocks)
    checked = table[table["analytic_volume"].notna()]
    assert set(checked["tool"]) == {1, 2}, table[["line", "tool", "analytic_volume"]]
    assert np.all(np.abs(checked["volume_ratio"] - 1) < 0.05), checked[["line", "tool", "volume_ratio"]]
    html = blocks.html.read_text(encoding="utf-8")
    assert "Stability lobes of T1 and its cutting blocks" in html and "Stability lobes of T2" in html


def test_a_rapid_move_into_the_material_is_reported_as_a_collision(tmp_path: Path, fmu_dir: Path) -> None:
    """The Workpiece sees the G0 that plunges 1 mm into the block and the process report names its line and tool,
    beside the program check's warning of the same line (tests/test_part_checks.py). The slot's own G1 plunge and
    the G0 retract out of the slot are no collision."""
    program = PROGRAM.replace("G0 Z5\nM5\n", "G0 Z5\nG0 X30 Y3\nG0 Z-1\nG0 Z5\nM5\n")
    result = milling_twin.simulate(milling_twin.load_scenario(write_part(tmp_path / "part", program=program),
                                                             fmu_dir), out=tmp_path / "runs")
    report = result.process_report
    assert report is not None
    collisions = [w for w in report.warnings if "rapid move (G0)" in w and "removes" in w]
    assert [w for w in report.warnings if "rapid move (G0)" in w and "where no earlier feed move has cut" in w]
    # line 9, "G0 Z-1": 1 mm deep, the 10 mm tool at y 3 cuts its circle between the block's edge (y 0) and the
    # slot (from y 5): 47 mm3
    assert len(collisions) == 1 and collisions[0].startswith("line 9: the rapid move (G0) with T1 removes"), \
        report.warnings
    assert "collision" in report.html.read_text(encoding="utf-8")
    clean = milling_twin.simulate(milling_twin.load_scenario(write_part(tmp_path / "clean"), fmu_dir),
                                  out=tmp_path / "clean_runs")
    assert not [w for w in clean.process_report.warnings if "rapid move" in w], clean.process_report.warnings
