"""Kind slot_forces on synthetic recordings made from the model: the binned waveform objective equals the
time-series one, the fit recovers the tool (coefficients and runout), the held-out feeds are predicted."""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import require_fmu
from milling_twin.models.cutting_force import CUTTING_FORCE
from milling_twin.orchestrator.calibrate import calibrate, load_spec
from milling_twin.orchestrator.calibrate import slot_forces as sf
from milling_twin.orchestrator.calibrate.fit import fit
from milling_twin.orchestrator.scenario import load_scenario
from test_slot_milling_validation import write_dynoware

REPO = Path(__file__).resolve().parents[1]
FEEDS = (300, 600, 900, 1200, 1500)
TOOL = {"Ktc": 950e6, "Krc": 250e6, "Kac": 150e6, "Kte": 16e3, "Kre": 19e3, "Kae": 18e3, "runout_offset": 12e-6}
PHASES = {300: 1234, 600: 77, 900: 2900, 1200: 1800, 1500: 600}  # on the 0.1 deg grid (of 3600)


def forces(feed: float, t: np.ndarray, tool: dict, phase: float) -> np.ndarray:
    omega = 6000 * 2 * math.pi / 60
    out = CUTTING_FORCE.evaluate(**tool, n_flutes=2, tool_diameter=0.025, helix_angle=math.radians(30),
                                 spindle_speed=omega, feed_velocity_x=feed / 60_000, axial_depth=0.003,
                                 angle=np.mod(phase + omega * (t - t[0]), 2 * math.pi),
                                 delayed_displacement_x=0.0, delayed_displacement_y=0.0)
    return np.column_stack([out["Fy"], out["Fx"], out["Fz"]])  # the files' axes


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """Five noise-free recordings of TOOL (20 revolutions at 10 kHz each)."""
    folder = tmp_path_factory.mktemp("slot_synthetic")
    t = 3.0 + np.arange(2000) * 1e-4
    for feed in FEEDS:
        write_dynoware(folder / f"6-n6000f{feed}ap3ae25.csv", t, forces(feed, t, TOOL, 2 * math.pi * PHASES[feed] / 3600))
    return folder


@pytest.fixture(scope="module")
def setup(data: Path, fmu_dir: Path):
    require_fmu(fmu_dir / "CuttingForce.fmu")
    spec = load_spec(REPO / "scenarios" / "calibration" / "slot_forces.toml")
    scenario = load_scenario(spec.scenario, fmu_dir)
    learn = sf.load_slot_data(data, spec.slot_forces.learning_feeds, "k", spec, 0, 2)
    return spec, scenario, learn


def test_binned_objective_equals_the_time_series_one(setup, data: Path) -> None:
    spec, scenario, learn = setup
    rng = np.random.default_rng(0)
    noisy = [replace(r, forces=r.forces + rng.normal(0, 20.0, r.forces.shape)) for r in learn.recordings]
    binned = sf.SlotData(noisy, 0, 2)
    params = sf._parameters(spec, scenario, sf.fitted_names(scenario, spec), {}) + sf._phase_parameters(binned)
    slot = sf.slot_model(scenario, spec, binned.recordings, [len(w) for w in binned.waves])
    model = sf.waveform_model(slot, binned, params)
    theta = np.array([800e6, 200e6, 100e6, 20e3, 15e3, 10e3, 5e-6, 0.3, 1.1, 2.0])
    weights = np.array([0.01, 0.02, 0.03])
    r, _ = model.residual_jacobian(theta, model.data_vector(np.concatenate(binned.waves), weights))
    binned_ssr = float(r @ r) + model.extra_ssr(weights)
    naive = 0.0
    for i, rec in enumerate(noisy):
        tool = dict(zip(slot.coefficients, theta[:7]))
        sim = forces(rec.feed, rec.time, tool, theta[7 + i])
        naive += float(np.sum(((sim - rec.forces) * weights) ** 2))
    assert binned_ssr == pytest.approx(naive, rel=1e-9)
    assert model.n_samples == 3 * 2000 * 3


def test_noise_free_waveform_fit_recovers_the_tool(setup) -> None:
    spec, scenario, learn = setup
    params = sf._parameters(spec, scenario, sf.fitted_names(scenario, spec), {}) + sf._phase_parameters(learn)
    slot = sf.slot_model(scenario, spec, learn.recordings, [len(w) for w in learn.waves])
    model = sf.waveform_model(slot, learn, params)
    fitted = [q.name.split(".")[1] for q in params if not q.nuisance]
    strategy = sf.alternating(sf.PhaseSearch(slot, learn), len(fitted), model.scale())
    start = np.array([q.initial for q in params])
    outcome = fit(model, np.concatenate(learn.waves), weights=[1.0] * 3, sigma=[None] * 3,
                  solver=replace(spec.solver, starts=1, max_iterations=100), statistics=spec.statistics,
                  strategy=strategy, starts=start[None, :])
    estimates = dict(zip(fitted, outcome.theta))
    for name, value in TOOL.items():
        assert estimates[name] == pytest.approx(value, rel=1e-6), name
    phases = outcome.theta[len(fitted):]
    truth = [2 * math.pi * PHASES[int(f)] / 3600 for f in spec.slot_forces.learning_feeds]
    assert np.allclose(np.mod(phases - truth + math.pi, 2 * math.pi) - math.pi, 0.0, atol=1e-9)


def test_the_whole_slot_calibration_predicts_the_held_out_feeds(data: Path, fmu_dir: Path, tmp_path: Path) -> None:
    require_fmu(fmu_dir / "CuttingForce.fmu")
    source = (REPO / "scenarios" / "calibration" / "slot_forces.toml").read_text()
    spec = tmp_path / "slot.toml"
    spec.write_text(source.replace('scenario = "../slot_milling.toml"',
                                   f'scenario = "{REPO / "scenarios" / "slot_milling.toml"}"')
                    .replace("starts = 4", "starts = 2"))
    result = calibrate(spec, fmu_dir, tmp_path / "out", data=data, progress=False)
    held = result.extra["held_out"]
    assert max(held["mean_abs_error"]["calibrated"][0] + held["mean_abs_error"]["calibrated"][1]) < 0.01
    assert min(held["r2"]["calibrated"][0] + held["r2"]["calibrated"][1]) > 0.99
    for name, value in TOOL.items():  # the waveform fit finds the tool, runout included
        assert result.fit.estimate(f"force.{name}") == pytest.approx(value, rel=1e-6), name
    # the regression of mean forces is biased by the runout (one flute's chip is clipped at 0 near entry)
    regression = result.extra["regression"]
    assert regression.estimate("force.Ktc") == pytest.approx(TOOL["Ktc"], rel=0.1)
    assert abs(regression.estimate("force.Ktc") / TOOL["Ktc"] - 1) > 0.01
    assert "Held-out feeds" in result.report_html.read_text()
    assert result.parameter_set == tmp_path / "out" / "calibration" / "slot_forces" / "slot_forces.params.toml"
    assert not (tmp_path / "slot_forces.params.toml").exists()
