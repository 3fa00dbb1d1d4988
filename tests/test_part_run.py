"""A whole-part scenario run as a user runs it (``milling-twin run PART.toml``): the Workpiece writes the final
Z-map into the run folder, the process report follows the run, the summary gives its headline; and the variable
step agrees with the all-fine-step run of the same part (the benchmark's figures in miniature)."""
from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import numpy as np

import milling_twin
from cases.part_case import write_part
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
