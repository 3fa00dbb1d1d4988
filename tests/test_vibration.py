"""ToolVibration against the analytic response of damped oscillators (both FMI versions)."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import OK, Slave, fmu_dir, fmu_id, require_fmu

FMUS = [fmu_dir() / "ToolVibration.fmu", fmu_dir() / "ToolVibration_fmi2.fmu"]
F, K, FREQ, ZETA = 250.0, 1.34e6, 922.0, 0.011  # N, N/m, Hz, 1: Altintas' single-mode tool


def step_response(t: np.ndarray, f: float, zeta: float, k: float) -> tuple[np.ndarray, np.ndarray]:
    """Displacement and velocity of q'' + 2 zeta wn q' + wn^2 q = wn^2 F/k from rest, F applied at t=0."""
    wn = 2 * math.pi * f
    wd, sigma = wn * math.sqrt(1 - zeta ** 2), zeta * wn
    decay = np.exp(-sigma * t)
    x = F / k * (1 - decay * (np.cos(wd * t) + sigma / wd * np.sin(wd * t)))
    v = F / k * decay * (wn ** 2 / wd) * np.sin(wd * t)
    return x, v


def run(fmu: Path, parameters: dict, forces: list[tuple[float, float]], h: float, steps: int,
        outputs: list[str]) -> np.ndarray:
    """Force (fx, fy) held for each block of ``steps`` steps; outputs after every step."""
    rows = []
    with Slave(require_fmu(fmu)) as slave:
        slave.instantiate()
        slave.initialize(parameters)
        for fx, fy in forces:
            slave.set({"force_x": fx, "force_y": fy})
            for _ in range(steps):
                assert slave.step(h) == OK
                rows.append(slave.get(outputs))
    return np.array(rows)


@pytest.mark.parametrize("fmu", FMUS, ids=fmu_id)
def test_forced_and_free_response_equal_the_analytic_oscillator(fmu: Path) -> None:
    """Step force for 20 ms, then released: forced response, then free decay (superposition)."""
    h, steps = 1e-5, 2000
    parameters = {"n_modes_x": 1, "n_modes_y": 1, "frequency_x1": FREQ, "damping_x1": ZETA,
                  "stiffness_x1": K, "frequency_y1": 2 * FREQ, "damping_y1": 0.05, "stiffness_y1": 4 * K}
    names = ["tip_displacement_x", "tip_velocity_x", "tip_displacement_y"]
    actual = run(fmu, parameters, [(F, -F), (0.0, 0.0)], h, steps, names)
    t = h * np.arange(1, 2 * steps + 1)
    t_off = np.clip(t - steps * h, 0.0, None)
    x_on, v_on = step_response(t, FREQ, ZETA, K)
    x_off, v_off = step_response(t_off, FREQ, ZETA, K)
    y_on, _ = step_response(t, 2 * FREQ, 0.05, 4 * K)
    y_off, _ = step_response(t_off, 2 * FREQ, 0.05, 4 * K)
    released = t > steps * h
    expected_x = x_on - np.where(released, x_off, 0.0)
    expected_v = v_on - np.where(released, v_off, 0.0)
    expected_y = -(y_on - np.where(released, y_off, 0.0))
    static = F / K
    assert np.max(np.abs(actual[:, 0] - expected_x)) < 1e-9 * static
    assert np.max(np.abs(actual[:, 1] - expected_v)) < 1e-9 * static * 2 * math.pi * FREQ
    assert np.max(np.abs(actual[:, 2] - expected_y)) < 1e-9 * static
    # independent of step_response: the first overshoot of a step-loaded oscillator
    overshoot = math.exp(-math.pi * ZETA / math.sqrt(1 - ZETA ** 2))
    assert np.max(actual[:steps, 0]) == pytest.approx(static * (1 + overshoot), rel=1e-3)


@pytest.mark.parametrize("fmu", FMUS, ids=fmu_id)
def test_exact_discretization_does_not_depend_on_the_step_size(fmu: Path) -> None:
    parameters = {"n_modes_x": 2, "n_modes_y": 0}
    coarse = run(fmu, parameters, [(F, 0.0), (-F, 0.0)], 1e-4, 50, ["tip_displacement_x", "sensor_displacement_x"])
    fine = run(fmu, parameters, [(F, 0.0), (-F, 0.0)], 1e-5, 500, ["tip_displacement_x", "sensor_displacement_x"])
    scale = np.max(np.abs(fine))
    assert np.max(np.abs(coarse - fine[9::10])) < 1e-11 * scale


def ring_down(fmu: Path, step: float, steps: int) -> np.ndarray:
    """Tip displacement and velocity x after each of ``steps`` free steps of ``step``, after a 5 ms push of F at
    10 us on a 2800 Hz, 3 % mode (1.25e-5 m static)."""
    rows = []
    with Slave(require_fmu(fmu)) as slave:
        slave.instantiate()
        slave.initialize({"n_modes_x": 1, "n_modes_y": 1, "frequency_x1": 2800.0, "damping_x1": 0.03,
                          "stiffness_x1": 2e7})
        slave.set({"force_x": F, "force_y": 0.0})
        for _ in range(500):
            assert slave.step(1e-5) == OK
        slave.set({"force_x": 0.0})
        for _ in range(steps):
            assert slave.step(step) == OK
            rows.append(slave.get(["tip_displacement_x", "tip_velocity_x"]))
    return np.array(rows)


@pytest.mark.parametrize("fmu", FMUS, ids=fmu_id)
def test_a_free_response_comes_to_rest_exactly_whatever_the_step(fmu: Path) -> None:
    """Rung down, the tool is exactly at rest (REST of models/vibration.py: 1e-30 m), stepped at 10 us or at 1 ms,
    not in subnormal numbers that differ between the two; it rests only from about 1e-30 m on, and stays."""
    fine, coarse = ring_down(fmu, 1e-5, 20_000), ring_down(fmu, 1e-3, 200)  # 200 ms each
    assert np.all(fine[-1] == 0.0) and np.all(coarse[-1] == 0.0)
    for response in (fine, coarse):
        resting = np.all(response == 0.0, axis=1)
        first = int(np.argmax(resting))
        assert first > 0 and np.all(resting[first:])          # once at rest, it stays
        assert 0.0 < np.abs(response[first - 1, 0]) < 1e-28     # the step before: still ringing, near 1e-30 m
    assert np.abs(fine[4_999, 0]) > 1e-20  # after 50 ms: 1.25e-5 m x exp(-528 / s x 0.05 s) ~ 4e-17 m, not at rest


@pytest.mark.parametrize("fmu", FMUS, ids=fmu_id)
def test_sensor_is_the_mode_shape_weighted_sum_and_acceleration_obeys_the_modal_equation(fmu: Path) -> None:
    parameters = {"n_modes_x": 2, "n_modes_y": 0, "shape_sensor_x1": 0.3, "shape_sensor_x2": -0.5,
                  "frequency_x2": 2400.0, "damping_x2": 0.02, "stiffness_x2": 8e6}
    outputs = ["tip_displacement_x", "sensor_displacement_x", "tip_acceleration_x", "tip_displacement_y"]
    actual = run(fmu, parameters, [(F, 0.0)], 1e-5, 300, outputs)
    t = 1e-5 * np.arange(1, 301)
    q1, v1 = step_response(t, FREQ, ZETA, K)
    q2, v2 = step_response(t, 2400.0, 0.02, 8e6)
    scale = F / K
    assert np.max(np.abs(actual[:, 0] - (q1 + q2))) < 1e-9 * scale
    assert np.max(np.abs(actual[:, 1] - (0.3 * q1 - 0.5 * q2))) < 1e-9 * scale
    accel = [(2 * math.pi * f) ** 2 * (F / k - q) - 2 * z * 2 * math.pi * f * v
             for f, z, k, q, v in ((FREQ, ZETA, K, q1, v1), (2400.0, 0.02, 8e6, q2, v2))]
    assert np.max(np.abs(actual[:, 2] - sum(accel))) < 1e-9 * scale * (2 * math.pi * 2400.0) ** 2
    assert np.all(actual[:, 3] == 0.0)  # no active mode in y
