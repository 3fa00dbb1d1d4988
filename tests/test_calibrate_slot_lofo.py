"""The slot-forces fit with a power law and the measuring chain, and the leave-one-feed-out report, on synthetic
recordings whose law and chain are known: Kienzle's exponential law, a one-mode chain with cross-coupling, noise.
The right model predicts every held-out feed, finds the truth inside its intervals, and the folds' estimates fall
inside each other's intervals; the chain's waveform equals the MeasuringChain's own time-domain response."""
from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from fmu_helpers import require_fmu
from milling_twin.models.cutting_force import CHIP_LAW_EXPONENTIAL, CUTTING_FORCE
from milling_twin.models.measuring_chain import frequency_response, simulate
from milling_twin.orchestrator.calibrate import load_spec
from milling_twin.orchestrator.calibrate import slot_forces as sf
from milling_twin.orchestrator.calibrate.scenario_fit import with_overrides
from milling_twin.orchestrator.calibrate.slot_lofo import (bound_table, coverage, leave_one_feed_out,
                                                            recorded_bound, summary)
from milling_twin.orchestrator.calibrate.slot_model import OVERSAMPLE
from milling_twin.orchestrator.scenario import load_scenario
from test_slot_milling_validation import write_dynoware

REPO = Path(__file__).resolve().parents[1]
FEEDS = (400, 900, 1400)
LAW = {"Ktc": 420e6, "Krc": 160e6, "Kac": 90e6, "mc_t": 0.25, "mc_r": 0.45, "mc_a": 0.3, "runout_offset": 10e-6}
CHAIN = {"n_modes": 1, "frequency_1": 950.0, "damping_1": 0.06, "gain_1_xx": 0.8, "gain_1_xy": 0.15,
         "gain_1_xz": 0.0, "gain_1_yx": -0.1, "gain_1_yy": 0.6, "gain_1_yz": 0.05, "gain_1_zx": 0.1,
         "gain_1_zy": 0.0, "gain_1_zz": 0.3}
PHASES = {400: 0.4, 900: 2.9, 1400: 5.1}
NOISE = 5.0  # N per sample
OMEGA = 6000 * 2 * math.pi / 60


def force_waveform(feed: float, phase: float, points: int) -> np.ndarray:
    """The force on the tool over one revolution from ``phase`` on ``points`` angles, in the files' axes."""
    angle = np.mod(phase + 2 * math.pi * np.arange(points) / points, 2 * math.pi)
    out = CUTTING_FORCE.evaluate(**LAW, chip_law=CHIP_LAW_EXPONENTIAL, n_flutes=2, tool_diameter=0.025,
                                 helix_angle=math.radians(30), spindle_speed=OMEGA, feed_velocity_x=feed / 60_000,
                                 axial_depth=0.003, angle=angle, delayed_displacement_x=0.0,
                                 delayed_displacement_y=0.0)
    return np.column_stack([out["Fy"], out["Fx"], out["Fz"]])


def measured_waveform(feed: float, phase: float, fine: int = 100 * OVERSAMPLE) -> np.ndarray:
    """One revolution (100 samples) as the dynamometer records it: the chain's response to every harmonic the
    10 kHz samples resolve (an ideal anti-aliasing filter), from the force on ``fine`` points (the fit's grid:
    with a finer one the 16 axial slices' staircase aliases 0.2 % of the range differently)."""
    spectrum = np.fft.rfft(force_waveform(feed, phase, fine), axis=0)
    response = frequency_response(CHAIN, np.arange(51) * 100.0)
    kept = np.zeros_like(spectrum)
    kept[:51] = np.einsum("kij,kj->ki", response, spectrum[:51])
    return np.fft.irfft(kept, n=fine, axis=0)[::fine // 100]


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> Path:
    """Three recordings of 30 revolutions at 10 kHz with white noise."""
    folder = tmp_path_factory.mktemp("slot_lofo")
    rng = np.random.default_rng(5)
    t = 1.0 + np.arange(3000) * 1e-4
    for feed in FEEDS:
        wave = np.tile(measured_waveform(feed, PHASES[feed]), (30, 1))
        write_dynoware(folder / f"6-n6000f{feed}ap3ae25.csv", t, wave + rng.normal(0.0, NOISE, wave.shape))
    return folder


@pytest.fixture(scope="module")
def setup(fmu_dir: Path):
    require_fmu(fmu_dir / "CuttingForce.fmu")
    require_fmu(fmu_dir / "MeasuringChain.fmu")
    spec = load_spec(REPO / "scenarios" / "calibration" / "slot_forces_chain.toml")
    spec = replace(spec, solver=replace(spec.solver, starts=1),
                   slot_forces=replace(spec.slot_forces, learning_feeds=FEEDS[:2], validation_feeds=FEEDS[2:]))
    scenario = with_overrides(load_scenario(spec.scenario, fmu_dir),
                              {"force.chip_law": CHIP_LAW_EXPONENTIAL, "chain.n_modes": 1})
    return spec, scenario


def test_the_model_waveform_through_the_chain_is_the_chains_time_domain_response(setup, data: Path) -> None:
    """SlotModel.waveform (the DFT path the fit differentiates) and fine_waveform (the phase search's) agree with
    each other and with models.measuring_chain.simulate, the chain's exact time-domain solution, in steady state."""
    spec, scenario = setup
    learn = sf.load_slot_data(data, FEEDS[:1], "k", spec, 0, 2)
    model = sf.slot_model(scenario, spec, learn.recordings, [100])
    theta = np.array([LAW[n] for n in model.coefficients] + [CHAIN[n] for n in model.chain])
    th, phase = ca.MX.sym("theta", theta.size), ca.MX.sym("phase")
    waveform = np.asarray(ca.Function("w", [th, phase], [model.waveform(th, 0, phase)])(theta, 0.7))
    np.testing.assert_allclose(waveform, measured_waveform(FEEDS[0], 0.7), atol=1e-9 * np.ptp(waveform))
    assert np.abs(waveform - measured_waveform(FEEDS[0], 0.7, 4000)).max() < 3e-3 * np.ptp(waveform)
    shift = round(0.7 / (2 * math.pi) * 3600)
    fine = model.fine_waveform(theta, 0, 3600)
    np.testing.assert_allclose(fine[(shift + np.arange(100) * 36) % 3600],
                               measured_waveform(FEEDS[0], shift * 2 * math.pi / 3600, 3600), atol=1e-6)
    # the time domain: 1 us steps over 8 revolutions from rest, the last revolution sampled
    step, per_rev = 1e-6, 10_000
    steps = np.arange(8 * per_rev)
    force = force_waveform(FEEDS[0], 0.7, per_rev)[steps % per_rev]
    response = simulate({k: v for k, v in CHAIN.items()}, force, step)[-per_rev:][::100]
    spread = np.ptp(waveform, axis=0)
    # the force's harmonics above 5 kHz (sharp edge-force changes) reach the time-domain response through the
    # chain's feedthrough; the samples' anti-aliasing removes them from the recorded waveform
    assert np.all(np.abs(response - waveform).max(axis=0) < 0.03 * spread)


def test_the_waveform_and_its_jacobian_compiled_and_in_threads_are_those_of_one_interpreted_thread(
        setup, data: Path) -> None:
    """The force mapped over the angles in several threads (every thread its own angles) and compiled to machine
    code (the same operations in the same order): the same numbers to the bit as casadi's virtual machine in one
    thread (the waveform the fit differentiates, its Jacobian, the phase search's fine waveform), for two
    recordings through one function (the feed its input)."""
    spec, scenario = setup
    learn = sf.load_slot_data(data, FEEDS[:2], "k", spec, 0, 2)
    model = sf.slot_model(scenario, spec, learn.recordings, [100, 100])
    assert model.varying == ["feed_velocity_x"]
    if not model.compile_options:
        pytest.skip("the force model is not compiled here (no working C compiler, or a preloaded sanitizer runtime)")
    models = [replace(model, threads=n, compile_options=options)
              for options in ({}, model.compile_options) for n in (1, 3)]
    theta = np.array([LAW[n] for n in models[0].coefficients] + [CHAIN[n] for n in models[0].chain])
    th, phase = ca.MX.sym("theta", theta.size), ca.MX.sym("phase")
    values = []
    for model in models:
        w = ca.vertcat(model.waveform(th, 0, phase), model.waveform(th, 1, phase + 1))
        f = ca.Function("w", [th, phase], [w, ca.jacobian(w, ca.vertcat(th, phase))])
        values.append([np.asarray(v) for v in f(theta, 0.7)] + [model.fine_waveform(theta, 1, 3600)])
    for other in values[1:]:
        for one, same in zip(values[0], other):
            assert np.array_equal(one, same)


@pytest.mark.ipopt
def test_leave_one_feed_out_with_the_right_law_and_chain(setup, data: Path) -> None:
    spec, scenario = setup
    folds = leave_one_feed_out(spec, scenario, data, 2)
    assert [f.held_feed for f in folds] == list(FEEDS)
    s = summary(folds)
    assert max(s["mean_abs_error"]) < 0.01, s
    assert min(s["mean_r2"]) > 0.99, s
    names = folds[0].names
    truth = {**{f"force.{k}": v for k, v in LAW.items()}, **{f"chain.{k}": v for k, v in CHAIN.items()}}
    for f in folds:  # every fold finds the truth inside (or within a hair of) its 95 % intervals
        inside = [f.ci[k, 0] - 1e-9 * abs(truth[n]) <= truth[n] <= f.ci[k, 1] + 1e-9 * abs(truth[n])
                  for k, n in enumerate(names)]
        assert np.mean(inside) >= 0.75, (f.held_feed, dict(zip(names, inside)))
    cov = coverage(folds)
    assert set(cov) >= {"force.Ktc", "force.mc_t", "chain.frequency_1"}
    assert np.mean(list(cov.values())) >= 0.6, cov


def test_the_report_shows_what_the_recordings_allow(setup, data: Path) -> None:
    """The feed interpolant beside the models: with three feeds the affine one only, every feed held out once;
    Kienzle's law is curved in the chip, so the end feeds' means are missed by more than the noise's share."""
    spec, _ = setup
    bound = recorded_bound(spec, data, 2)
    assert list(bound) == [1]
    assert [f.held_feed for f in bound[1]] == list(FEEDS)
    assert abs(bound[1][0].mean_error).max() > 0.01  # 400 mm/min extrapolated from 900 and 1400
    table = bound_table(bound)
    assert [row[1] for row in table.rows] == ["400 mm/min", "900 mm/min", "1400 mm/min", "mean |error|, mean r2"]


def test_a_parameter_the_scenario_does_not_fit_is_refused_naming_its_key(setup) -> None:
    """A section for a chain mode beyond n_modes (or any variable the kind does not fit) fails before any fit; a
    section for a coefficient of another chip-thickness law is ignored (one spec serves every law)."""
    from milling_twin.orchestrator.calibrate.errors import CalibrationSpecError
    from milling_twin.orchestrator.calibrate.spec import ParameterSpec
    from milling_twin.orchestrator.scenario import Ref

    spec, scenario = setup
    names = sf.fitted_names(scenario, spec)
    assert names["force"] == ["Ktc", "Krc", "Kac", "mc_t", "mc_r", "mc_a", "runout_offset"]
    assert names["chain"][:2] == ["frequency_1", "damping_1"] and len(names["chain"]) == 11
    assert "force.Kte" in {p.name for p in spec.parameters}  # the linear law's section, ignored under law 2
    assert [q.name for q in sf._parameters(spec, scenario, names, {})][:3] == ["force.Ktc", "force.Krc", "force.Kac"]
    extra = ParameterSpec(Ref("chain", "frequency_2"), '[parameters."chain.frequency_2"]', min=100.0, max=900.0)
    with pytest.raises(CalibrationSpecError, match=r'\[parameters\."chain\.frequency_2"\].*not chain\.frequency_2'):
        sf._parameters(replace(spec, parameters=spec.parameters + (extra,)), scenario, names, {})
