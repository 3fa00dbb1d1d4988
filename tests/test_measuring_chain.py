"""MeasuringChain: the FMU (FMI 2 and 3) against the model's Python reference, the pass-through and static
gain, the frequency response of the sampled FMU, cross-coupling, bad parameters; the Python reference against
an independent discretization (scipy's matrix exponential)."""
from __future__ import annotations

import math
from pathlib import Path

import casadi as ca
import numpy as np
import pytest
from scipy.linalg import expm

from fmu_helpers import ERROR, OK, Slave, fmu_dir, fmu_id, require_fmu, status_of
from milling_twin.models.measuring_chain import (
    AXES,
    MAX_MODES,
    MEASURING_CHAIN,
    feedthrough,
    frequency_response,
    frequency_response_parts,
    gain_name,
    sampled_frequency_response,
    simulate,
    zero_order_hold,
)

FMUS = [fmu_dir() / "MeasuringChain.fmu", fmu_dir() / "MeasuringChain_fmi2.fmu"]
OUTPUTS = [f"measured_{a}" for a in AXES]
INPUTS = [f"force_{a}" for a in AXES]

# Three modes with cross-coupling: the gains of each axis do not sum to 1, so there is a direct feedthrough too.
CHAIN = {"n_modes": 3, "frequency_1": 900.0, "damping_1": 0.05, "frequency_2": 1700.0, "damping_2": 0.04,
         "frequency_3": 3100.0, "damping_3": 0.08,
         "gain_1_xx": 0.8, "gain_1_yx": 0.3, "gain_1_xy": -0.2, "gain_1_yy": 0.6, "gain_1_zx": 0.1,
         "gain_2_xx": 0.2, "gain_2_yy": 0.5, "gain_2_zz": 0.5, "gain_2_zy": -0.15,
         "gain_3_zz": 0.7, "gain_3_xz": 0.05}


def run(fmu: Path, parameters: dict, forces: np.ndarray, h: float) -> np.ndarray:
    """Force k set, one step of h, the outputs read (force k still set): (n, 3)."""
    rows = []
    with Slave(require_fmu(fmu)) as slave:
        slave.instantiate()
        slave.initialize(parameters)
        for force in forces:
            slave.set(dict(zip(INPUTS, force)))
            assert slave.step(h) == OK
            rows.append(slave.get(OUTPUTS))
    return np.array(rows)


def periodic_force(t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Per axis a mean force plus the harmonics of 100 Hz up to 2 kHz with random amplitudes and phases: (n, 3)."""
    columns = []
    for _ in AXES:
        amplitudes = rng.uniform(5.0, 50.0, 20)
        phases = rng.uniform(0.0, 2 * math.pi, 20)
        harmonics = sum(a * np.cos(2 * math.pi * 100.0 * k * t + p)
                        for k, a, p in zip(range(1, 21), amplitudes, phases))
        columns.append(rng.uniform(-300.0, 300.0) + harmonics)
    return np.stack(columns, axis=1)


@pytest.mark.parametrize("fmu", FMUS, ids=fmu_id)
def test_fmu_equals_the_python_reference_step_by_step(fmu: Path) -> None:
    rng = np.random.default_rng(5)
    h = 1e-5
    forces = periodic_force(h * np.arange(3000), rng) + rng.normal(0.0, 20.0, (3000, 3))
    actual = run(fmu, CHAIN, forces, h)
    expected = simulate(CHAIN, forces, h)
    scale = np.max(np.abs(expected))
    assert np.max(np.abs(actual - expected)) < 1e-12 * scale
    assert np.max(np.abs(expected - forces)) > 0.05 * scale  # the chain does change the force


def test_the_python_reference_is_the_exact_zero_order_hold_discretization() -> None:
    """simulate() against the continuous state-space model discretized with scipy's matrix exponential."""
    h, n = 2e-5, 1500
    rng = np.random.default_rng(8)
    forces = periodic_force(h * np.arange(n), rng)
    v = {**MEASURING_CHAIN.defaults(), **CHAIN}
    measured = forces.copy()
    for i in range(int(v["n_modes"])):
        w, zeta = 2 * math.pi * v[f"frequency_{i + 1}"], v[f"damping_{i + 1}"]
        a = np.array([[0.0, 1.0, 0.0], [-w * w, -2 * zeta * w, w * w], [0.0, 0.0, 0.0]])  # (q, q', F held)
        phi = expm(a * h)
        gains = np.array([[v[gain_name(i, o, j)] for j in AXES] for o in AXES])
        for j in range(3):
            state = np.zeros(3)
            q = np.empty(n)
            for k in range(n):
                state[2] = forces[k, j]
                state = phi @ state
                q[k] = state[0]
            measured += np.outer(q - forces[:, j], gains[:, j])
    assert np.max(np.abs(simulate(CHAIN, forces, h) - measured)) < 1e-10 * np.max(np.abs(measured))


@pytest.mark.parametrize("fmu", FMUS, ids=fmu_id)
def test_no_modes_pass_the_force_through_unchanged(fmu: Path) -> None:
    rng = np.random.default_rng(1)
    forces = rng.uniform(-5e3, 5e3, (200, 3))
    gains = {gain_name(i, o, j): 0.7 for i in range(MAX_MODES) for o in AXES for j in AXES}
    actual = run(fmu, {"n_modes": 0, **gains}, forces, 1e-5)
    assert np.array_equal(actual, forces)


@pytest.mark.parametrize("fmu", FMUS, ids=fmu_id)
def test_static_gain_is_the_identity(fmu: Path) -> None:
    """A constant force, any gains: once the modes have settled the measured force is the applied one."""
    force = np.array([[420.0, -180.0, 95.0]])
    actual = run(fmu, CHAIN, np.repeat(force, 2000, axis=0), 1e-4)
    assert np.max(np.abs(actual[0] - force[0])) > 10.0  # the first step is not yet settled
    assert np.max(np.abs(actual[-1] - force[0])) < 1e-12 * np.max(np.abs(force))
    assert np.array_equal(frequency_response(CHAIN, [0.0])[0], np.eye(3))


@pytest.mark.parametrize("fmu", FMUS, ids=fmu_id)
def test_periodic_force_reaches_the_frequency_response_with_the_hold(fmu: Path) -> None:
    """Harmonics of 100 Hz up to 2 kHz on every axis, run 0.12 s at 10 us until the transient has decayed below
    1e-10, the last period (10 ms) analysed: each harmonic of the measured force equals the frequency
    response's prediction (the modal part through the hold e^{-jwh/2} sinc(wh/2), the feedthrough a step late
    as this loop reads it) to 1e-6 of the largest harmonic (measured 1.8e-7), and the exact sampled response to
    1e-11 (measured 2.4e-14). Without the hold the continuous H is off by 3.2 %, H e^{-jwh/2} alone by 0.21 %
    (the feedthrough's half step)."""
    h, period, periods = 1e-5, 1000, 12
    rng = np.random.default_rng(3)
    t = h * np.arange(period * periods + 1)
    forces = periodic_force(t, rng)
    measured = run(fmu, CHAIN, forces[:-1], h)  # row m: the outputs at t[m + 1]
    u = np.fft.fft(forces[-period:], axis=0) / period  # samples at t[m] for the last period
    y = np.fft.fft(measured[-period:], axis=0) / period  # outputs at the same t[m]
    bins = np.arange(1, 21)
    frequencies = 100.0 * bins
    hold = zero_order_hold(frequencies, h)[:, None, None]
    late = np.exp(-2j * math.pi * frequencies * h)[:, None, None]
    d = feedthrough(CHAIN)
    predicted = (frequency_response(CHAIN, frequencies) - d) * hold + d * late
    exact = sampled_frequency_response(CHAIN, frequencies, h, set_before_read=False)
    y_predicted = np.einsum("kij,kj->ki", predicted, u[bins])
    y_exact = np.einsum("kij,kj->ki", exact, u[bins])
    scale = np.max(np.abs(y[bins]))
    assert np.max(np.abs(y[bins] - y_predicted)) < 1e-6 * scale
    assert np.max(np.abs(y[bins] - y_exact)) < 1e-11 * scale
    assert np.max(np.abs(y[0] - u[0])) < 1e-12 * np.max(np.abs(u[0]))  # the mean force passes unchanged
    # without the hold's delay the prediction is off by far more: what the hold does is visible
    y_continuous = np.einsum("kij,kj->ki", frequency_response(CHAIN, frequencies), u[bins])
    assert np.max(np.abs(y[bins] - y_continuous)) > 1e-2 * scale


def test_sampled_response_read_after_the_new_force_is_set() -> None:
    """The orchestrator's order (the next force set before the outputs are read): the feedthrough has no delay."""
    frequencies = np.array([100.0, 900.0, 2000.0])
    h = 1e-5
    hold = zero_order_hold(frequencies, h)[:, None, None]
    d = feedthrough(CHAIN)
    predicted = (frequency_response(CHAIN, frequencies) - d) * hold + d
    exact = sampled_frequency_response(CHAIN, frequencies, h, set_before_read=True)
    assert np.max(np.abs(exact - predicted)) < 1e-6 * np.max(np.abs(exact))


@pytest.mark.parametrize("fmu", FMUS, ids=fmu_id)
def test_cross_coupling_moves_force_from_x_to_y(fmu: Path) -> None:
    """A step force in x only, one mode with gain 0.4 from x to y: measured_y is 0.4 (q - F), the decaying
    oscillation of the step response; measured_x (no xx gain) and measured_z stay the applied force."""
    f, zeta, g, force, h = 1200.0, 0.06, 0.4, 500.0, 1e-5
    parameters = {"n_modes": 1, "frequency_1": f, "damping_1": zeta, gain_name(0, "y", "x"): g}
    actual = run(fmu, parameters, np.repeat([[force, 0.0, 0.0]], 400, axis=0), h)
    t = h * np.arange(1, 401)
    w = 2 * math.pi * f
    wd, sigma = w * math.sqrt(1 - zeta ** 2), zeta * w
    expected_y = -g * force * np.exp(-sigma * t) * (np.cos(wd * t) + sigma / wd * np.sin(wd * t))
    assert np.all(actual[:, 0] == force) and np.all(actual[:, 2] == 0.0)
    assert np.max(np.abs(actual[:, 1] - expected_y)) < 1e-9 * force
    assert np.max(np.abs(actual[:, 1])) > 0.3 * g * force


BAD = [("frequency_1", -800.0, "= -800 Hz is out of its allowed range [1, 50000] Hz"),
       ("damping_2", 1.0, "= 1 is out of its allowed range [0.0001, 0.95]"),
       ("n_modes", 5, "= 5 is out of its allowed range [0, 4]"),
       ("gain_3_zy", 1e3, "= 1000 is out of its allowed range [-100, 100]")]


@pytest.mark.parametrize("fmu", FMUS, ids=fmu_id)
@pytest.mark.parametrize("name, value, message", BAD, ids=[b[0] for b in BAD])
def test_bad_parameters_are_an_fmi_error_naming_the_variable(fmu: Path, name: str, value: float,
                                                             message: str) -> None:
    with Slave(require_fmu(fmu)) as slave:
        slave.instantiate()
        assert status_of(lambda: slave.set({name: value})) == ERROR
        assert f"variable '{name}' {message}" in slave.last_error()
        slave.fmu.reset()
        slave.initialize()  # the rejected value was not applied
        assert slave.get(["n_modes"])[0] == 0


def test_casadi_parts_are_the_numeric_response_and_differentiable() -> None:
    frequencies = [150.0, 880.0, 1900.0]
    numeric = frequency_response(CHAIN, frequencies)
    f1 = ca.SX.sym("f1")
    real, imag = frequency_response_parts({**CHAIN, "frequency_1": f1}, frequencies)
    function = ca.Function("H", [f1], [ca.vertcat(*real), ca.vertcat(*imag)])
    re, im = (np.asarray(x).reshape(-1, 3, 3) for x in function(CHAIN["frequency_1"]))
    assert np.max(np.abs(re + 1j * im - numeric)) < 1e-12 * np.max(np.abs(numeric))
    # the derivative with respect to the mode's frequency, against a central difference
    derivative = np.array([np.asarray(ca.Function("dH", [f1], [ca.jacobian(r, f1)])(900.0)).reshape(3, 3, order="F")
                           for r in real])
    step = 1e-3
    difference = (frequency_response({**CHAIN, "frequency_1": 900.0 + step}, frequencies)
                  - frequency_response({**CHAIN, "frequency_1": 900.0 - step}, frequencies)).real / (2 * step)
    assert np.max(np.abs(derivative - difference)) < 1e-6 * np.max(np.abs(difference))
    assert np.max(np.abs(difference)) > 1e-3


def test_unknown_parameters_and_bad_shapes_are_refused_by_name() -> None:
    with pytest.raises(ValueError, match="'frequency_5'"):
        frequency_response({"frequency_5": 1.0}, [10.0])
    with pytest.raises(ValueError, match=r"forces must be \(n, 3\), got \(10, 2\)"):
        simulate(CHAIN, np.zeros((10, 2)), 1e-5)
