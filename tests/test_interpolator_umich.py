"""Part-program reconstruction from recorded runs (orchestrator/gcode/reconstruct.py) and the scenario running
the Interpolator on it (scenarios/umich_motion.toml, scenarios/programs/)."""
from __future__ import annotations

import math
import subprocess
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from scipy.spatial import cKDTree

from fmu_helpers import OK, Slave, fmu_dir, fmu_file_name, repo_root, require_fmu
from milling_twin.models import interpolator as ip
from milling_twin.models.units import convert
from milling_twin.orchestrator.gcode import reconstruct as rc

REPO = repo_root()
RECORDING = REPO / "scenarios" / "data" / "umich_experiment_01.csv"
PROGRAM = REPO / "scenarios" / "programs" / "umich_01.nc"
SCENARIO = REPO / "scenarios" / "umich_motion.toml"
DRIVER = REPO / "build" / "tools" / "interp_run"


def test_line_number_artefacts_are_removed() -> None:
    recorded = np.array([5, 5, 2, 5, 6, 2, 7, 7, 9, 7, 7])
    assert rc.clean_sequence(recorded).tolist() == [5, 5, 5, 5, 6, 7, 7, 7, 7, 7, 7]
    assert rc.clean_sequence(np.array([1, 2, 2, 3])).tolist() == [1, 2, 2, 3]  # a real line 2 stays


def test_three_significant_digits_give_the_quantum() -> None:
    assert rc.quantum_of(np.array([198.0, 73.2, 5.5, -120.0, 0.0])).tolist() == pytest.approx(
        [1.0, 0.1, 0.01, 1.0, 1e-5])


def test_fusion_recovers_positions_below_the_quantum() -> None:
    t = np.arange(0, 30, 0.1)
    x = 150 + 20 * np.sin(0.3 * t) + 2 * t          # mm, crossing 100 mm steps of resolution 1 mm
    v = 20 * 0.3 * np.cos(0.3 * t) + 2
    q = np.round(x / rc.quantum_of(x)) * rc.quantum_of(x)
    fused = rc.fuse_positions(q, v)
    assert np.sqrt(np.mean((q - x) ** 2)) > 0.25
    assert np.sqrt(np.mean((fused - x) ** 2)) < 0.03


def test_arcs_and_lines_are_fitted() -> None:
    a = np.linspace(0, math.pi / 2, 12)
    line1 = np.column_stack([np.linspace(-10, 0, 8), np.full(8, -5.0), np.zeros(8)])
    arc = np.column_stack([5 * np.sin(a), -5 * np.cos(a), np.zeros(12)])       # centre (0, 0), ccw
    line2 = np.column_stack([np.full(8, 5.0), np.linspace(0, 10, 8), np.zeros(8)])
    points = np.vstack([line1, arc[1:], line2[1:]])
    fits = rc._fit_piece(points, allow_arcs=True)
    assert [f[0] for f in fits] == ["G1", "G3", "G1"]
    assert fits[1][2] == pytest.approx([0, 0, 0], abs=1e-7)
    centre, ccw, deviation = rc._arc_through(arc[0], arc[-1], arc[1:-1])
    assert ccw and deviation < 1e-7 and centre == pytest.approx([0, 0, 0], abs=1e-7)
    assert rc._arc_through(arc[-1], arc[0], arc[-2:0:-1])[1] is False


@pytest.fixture(scope="module")
def reconstruction() -> rc.Reconstruction:
    return rc.reconstruct(RECORDING)


def test_the_committed_program_is_what_the_tool_writes(reconstruction: rc.Reconstruction) -> None:
    assert PROGRAM.read_text() == reconstruction.program()
    assert reconstruction.stats["arcs"] >= 40 and reconstruction.stats["lines"] >= 40


def run_program(params: dict[str, float], tmp_path: Path) -> pd.DataFrame:
    csv = tmp_path / "ticks.csv"
    args = [str(DRIVER), "--csv", str(csv)]
    for name, value in params.items():
        args += ["--param", f"{name}={value!r}"]
    subprocess.run(args + [str(PROGRAM)], check=True, capture_output=True)
    return pd.read_csv(csv)


def scenario_parameters() -> dict[str, float]:
    """The scenario's numeric parameters in SI (the orchestrator's conversion, done here by models.units)."""
    with open(SCENARIO, "rb") as f:
        table = tomllib.load(f)["fmus"]["interp"]["parameters"]
    out = {}
    for name, value in table.items():
        if name == "program":
            continue
        if isinstance(value, dict):
            unit = ip.INTERPOLATOR.variable(name).unit
            value = float(convert(value["value"], value["unit"], unit))
        out[name] = float(value)
    return out


def test_the_program_reproduces_the_recorded_path_and_time(reconstruction: rc.Reconstruction, tmp_path: Path) -> None:
    data = pd.read_csv(RECORDING)
    ticks = run_program(scenario_parameters(), tmp_path)
    path = ticks[["x", "y", "z"]].to_numpy() * 1e3
    distance, _ = cKDTree(path).query(reconstruction.positions)
    assert distance.max() <= 0.12 and np.sqrt(np.mean(distance ** 2)) <= 0.05
    raw, _ = cKDTree(path).query(data[[f"{a}1_CommandPosition" for a in "XYZ"]].to_numpy())
    assert np.sqrt(np.mean(raw ** 2)) <= 0.3  # the raw positions' resolution is 1 mm in X
    speed = np.linalg.norm(data[[f"{a}1_CommandVelocity" for a in "XYZ"]].to_numpy(), axis=1)
    moving = np.count_nonzero(speed > 0.05) * 0.1
    assert moving * 0.99 <= len(ticks) * 1e-3 <= len(data) * 0.1 * 1.01
    recorded = set(rc.clean_sequence(data["M1_sequence_number"].to_numpy()).tolist())
    program = ip.parse_program(PROGRAM.read_text(), ip.default_parameters())
    assert {m.block for m in program.moves} - {0} <= recorded


def test_the_scenario_names_the_program_and_the_recording() -> None:
    with open(SCENARIO, "rb") as f:
        table = tomllib.load(f)
    assert (SCENARIO.parent / table["fmus"]["interp"]["parameters"]["program"]["path"]).resolve() == PROGRAM.resolve()
    assert (SCENARIO.parent / table["recorded"]["file"]).resolve() == RECORDING.resolve()
    start = [table["fmus"]["interp"]["parameters"][f"start_{a}"]["value"] for a in "xyz"]
    first = [float(w[1:]) for w in PROGRAM.read_text().splitlines()[5].split()[1:]]
    assert start == first


def test_the_scenario_runs_in_the_orchestrator(tmp_path: Path) -> None:
    """The program is a String parameter given as { path = ... } relative to the scenario; both stepping
    paths run it to the end of the program, at rest on its last point."""
    from milling_twin.orchestrator.master import run
    from milling_twin.orchestrator.results import load_results
    from milling_twin.orchestrator.scenario import load_scenario

    scenario = load_scenario(SCENARIO, fmu_dir())
    assert scenario.instance("interp").parameters["program"] == str(PROGRAM.resolve())
    frames = []
    for stepping in ("python", "fast"):
        result = run(scenario, tmp_path / stepping, progress=False, stepping=stepping)
        assert result.status == "completed" and result.stepping == stepping
        frames.append(load_results(result.run_dir))
    assert frames[0].equals(frames[1])
    last = frames[0].iloc[-1]
    assert last["interp.finished"] and last["interp.feed"] == 0.0


def test_the_fmu_runs_the_scenario_setup(tmp_path: Path) -> None:
    """What the scenario does, driven by hand (fmpy): the FMU with the scenario's parameters and program, 10 ms
    steps; its positions follow the recorded actual positions (time axes aligned at the start) within 3 mm RMS
    — the rest is the alignment module's job (the recording has pauses the program has not)."""
    data = pd.read_csv(RECORDING)
    with Slave(require_fmu(fmu_dir() / fmu_file_name("Interpolator", 3))) as slave:
        slave.instantiate()
        slave.enter_initialization()
        slave.fmu.setString([slave.vr["program"]], [str(PROGRAM)])
        slave.set(scenario_parameters())
        slave.exit_initialization()
        rows = []
        for _ in range(len(data) * 10):
            assert slave.step(0.01) == OK
            rows.append(slave.get(["x", "y", "z", "finished", "block_number"]))
        rows = np.array(rows)
    assert rows[-1, 3] == 1.0
    simulated = rows[9::10, :3] * 1e3  # at 0.1 s, 0.2 s, ...
    actual = data[[f"{a}1_ActualPosition" for a in "XYZ"]].to_numpy()[1:]
    n = min(len(simulated), len(actual))
    simulated, actual = simulated[:n], actual[:n]
    rms = np.sqrt(np.mean(np.sum((simulated - actual) ** 2, axis=1)))
    assert rms < 3.0, rms
    recorded = set(rc.clean_sequence(data["M1_sequence_number"].to_numpy()).tolist())
    assert set(rows[:, 4].astype(int)) - {0} <= recorded
