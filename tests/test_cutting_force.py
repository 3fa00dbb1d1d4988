"""CuttingForce against closed forms and physics, both FMI versions: Altintas' mean forces, the
regenerative chip (history ring, delayed displacement, a displacement step lasting one tooth period),
the chatter onset of the force/vibration loop at Altintas' stability limit, and the step size."""
from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import ERROR, OK, WARNING, Slave, assert_close, fmu_dir, fmu_id, require_fmu
from milling_twin.models.cutting_force import (
    AL7075_CARBIDE,
    CUTTING_FORCE,
    DisplacementHistory,
    MAX_PASSES,
    OMEGA_MIN,
    TWO_PI,
    identify_slot_coefficients,
    mean_forces,
    mean_slot_forces,
    reference_trajectory,
)
from milling_twin.models.stability import Mode, stability_lobes

REPO = Path(__file__).resolve().parents[1]
FMUS = [fmu_dir() / "CuttingForce.fmu", fmu_dir() / "CuttingForce_fmi2.fmu"]
RPM = 6000.0
OMEGA = RPM * TWO_PI / 60
OUTPUTS = ["Fx", "Fy", "Fz", "torque", "power", "spindle_angle", "feed_per_tooth"]


@pytest.fixture(params=FMUS, ids=fmu_id)
def fmu(request) -> Path:
    return require_fmu(request.param)


def test_constants_of_model_c_are_generated_from_the_model() -> None:
    from milling_twin.models.codegen import generate_constants

    source = (REPO / "fmus" / "force" / "model.c").read_text()
    assert '#include "model_constants.h"' in source and "#define OMEGA_MIN" not in source
    defines = dict(re.findall(r"#define (\w+) ([0-9.eE+-]+)", generate_constants(CUTTING_FORCE)))
    assert float(defines["OMEGA_MIN"]) == OMEGA_MIN
    assert float(defines["TWO_PI"]) == TWO_PI


def test_coefficient_units() -> None:
    from milling_twin.models.units import convert

    assert convert(767.01, "N/mm2", "N/m2") == pytest.approx(767.01e6, rel=1e-15)
    assert convert(1.0, "MPa", "N/mm2") == 1.0
    assert CUTTING_FORCE.variable("Ktc").unit == "N/m2" and CUTTING_FORCE.variable("Kte").unit == "N/m"


def test_slot_closed_form_is_the_general_one_and_identification_inverts_it() -> None:
    coefficients = {"Ktc": 1.8e9, "Krc": 6e8, "Kac": -3e8, "Kte": 3e4, "Kre": 4e4, "Kae": 5e3}
    slot = mean_slot_forces(**coefficients, n_flutes=3, axial_depth=0.004, feed_per_tooth=8e-5)
    general = mean_forces(**coefficients, n_flutes=3, axial_depth=0.004, feed_per_tooth=8e-5)
    assert slot == pytest.approx(general, rel=1e-12)
    feeds = [2e-5, 5e-5, 1e-4, 1.5e-4]
    means = [mean_slot_forces(**coefficients, n_flutes=3, axial_depth=0.004, feed_per_tooth=c) for c in feeds]
    identified = identify_slot_coefficients(feeds, *([m[a] for m in means] for a in ("Fx", "Fy", "Fz")),
                                            n_flutes=3, axial_depth=0.004)
    assert identified == pytest.approx(coefficients, rel=1e-9)


# ---- mean forces over whole revolutions: the FMU against Altintas' closed forms ----

CASES = {
    # name: (parameters, feed direction [deg], feed per tooth [m], window [rad])
    "slot_straight_flutes": ({"n_flutes": 2, "helix_angle": 0.0}, 0.0, 1e-4, (0.0, math.pi)),
    "slot_helix30_3_flutes_titanium_like": (
        {"n_flutes": 3, "helix_angle": math.radians(30), "Ktc": 1.8e9, "Krc": 6e8, "Kac": 4e8, "Kte": 3e4,
         "Kre": 4e4, "Kae": 5e3}, 0.0, 5e-5, (0.0, math.pi)),
    "half_immersion_down_milling_helix30_feed_at_120deg": (
        {"n_flutes": 4, "helix_angle": math.radians(30)}, 120.0, 8e-5, (math.pi / 2, math.pi)),
    # the power laws (Kienzle's exponential law, and the power law with edge terms): their mean forces
    "slot_kienzle_law_helix30": (
        {"n_flutes": 2, "helix_angle": math.radians(30), "chip_law": 2, "Ktc": 1.2e9, "Krc": 4e8, "Kac": 2e8,
         "mc_t": 0.25, "mc_r": 0.5, "mc_a": 0.35}, 0.0, 5e-5, (0.0, math.pi)),
    "up_milling_power_edge_law_feed_at_45deg": (
        {"n_flutes": 3, "helix_angle": math.radians(20), "chip_law": 3, "mc_t": 0.2, "mc_r": -0.3, "mc_a": 0.6},
        45.0, 8e-5, (0.3, 2.0)),
}
LAW = ("chip_law", "mc_t", "mc_r", "mc_a")


def revolution_mean(fmu: Path, parameters: dict, inputs: dict, steps_per_revolution: int) -> np.ndarray:
    """Outputs averaged over one revolution sampled at the midpoints of steps_per_revolution equal
    angle intervals (a first half step, then whole steps): the midpoint rule of the period integral."""
    h = TWO_PI / OMEGA / steps_per_revolution
    rows = []
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize({**parameters, **inputs})
        assert slave.step(h / 2) == OK
        rows.append(slave.get(OUTPUTS))
        for _ in range(steps_per_revolution - 1):
            assert slave.step(h) == OK
            rows.append(slave.get(OUTPUTS))
    return np.mean(rows, axis=0)


@pytest.mark.parametrize("case", CASES)
def test_mean_forces_equal_the_closed_form(fmu: Path, case: str) -> None:
    parameters, direction, feed_per_tooth, (entry, exit_) = CASES[case]
    parameters = {"axial_depth": 0.003, "tool_diameter": 0.01, **parameters}
    n = parameters["n_flutes"]
    speed = feed_per_tooth * n * OMEGA / TWO_PI
    theta = math.radians(direction)
    inputs = {"spindle_speed": OMEGA, "feed_velocity_x": speed * math.cos(theta),
              "feed_velocity_y": speed * math.sin(theta), "entry_angle": entry, "exit_angle": exit_}
    mean = dict(zip(OUTPUTS, revolution_mean(fmu, {k: v for k, v in parameters.items() if k != "axial_depth"},
                                             {**inputs, "axial_depth": parameters["axial_depth"]}, 2000)))
    coefficients = {k: parameters.get(k, AL7075_CARBIDE[k]) for k in AL7075_CARBIDE}
    law = {k: parameters[k] for k in LAW if k in parameters}
    closed = mean_forces(**coefficients, n_flutes=n, axial_depth=0.003, feed_per_tooth=feed_per_tooth,
                         entry_angle=entry, exit_angle=exit_, **law)
    # the closed form has the feed along +x: rotate it into the feed direction
    fx = closed["Fx"] * math.cos(theta) - closed["Fy"] * math.sin(theta)
    fy = closed["Fx"] * math.sin(theta) + closed["Fy"] * math.cos(theta)
    torque = closed["torque_per_radius"] * 0.005
    expected = {"Fx": fx, "Fy": fy, "Fz": closed["Fz"], "torque": torque, "power": torque * OMEGA}
    for name, value in expected.items():
        assert mean[name] == pytest.approx(value, rel=1e-3), f"{case}: mean {name}"
    assert mean["feed_per_tooth"] == pytest.approx(feed_per_tooth, rel=1e-12)
    if case.startswith("slot"):  # and Altintas' slotting formulae themselves
        slot = mean_slot_forces(**coefficients, n_flutes=n, axial_depth=0.003, feed_per_tooth=feed_per_tooth, **law)
        assert [mean["Fx"], mean["Fy"], mean["Fz"]] == pytest.approx([slot["Fx"], slot["Fy"], slot["Fz"]], rel=1e-3)


def test_power_laws_reduce_to_the_linear_and_the_exponential_law() -> None:
    """Law 3 with every m_c = 0 is law 1 bit for bit (the size-effect factor is exactly 1), law 3 without edge
    coefficients is law 2; law 2 ignores the edge coefficients; the mean forces of law 3 at m_c = 0 are Altintas'."""
    rng = np.random.default_rng(3)
    base = {"n_flutes": 3, "spindle_speed": OMEGA, "feed_velocity_x": 0.02, "feed_velocity_y": -0.01,
            "helix_angle": 0.4, "runout_offset": 1e-5, "angle": rng.uniform(0, TWO_PI, 200)}
    outputs = ("Fx", "Fy", "Fz", "torque")

    def forces(**values: float) -> np.ndarray:
        result = CUTTING_FORCE.evaluate(**base, **values)
        return np.array([result[k] for k in outputs])

    np.testing.assert_array_equal(forces(chip_law=3), forces(chip_law=1))
    kienzle = {"mc_t": 0.3, "mc_r": 0.5, "mc_a": 0.1}
    np.testing.assert_array_equal(forces(chip_law=2, **kienzle),
                                  forces(chip_law=3, Kte=0.0, Kre=0.0, Kae=0.0, **kienzle))
    np.testing.assert_array_equal(forces(chip_law=2, **kienzle), forces(chip_law=2, Kte=1e4, Kre=-3e3, **kienzle))
    assert not np.allclose(forces(chip_law=2, **kienzle), forces(chip_law=1))
    linear = mean_slot_forces(**AL7075_CARBIDE, n_flutes=2, axial_depth=0.003, feed_per_tooth=6e-5)
    power = mean_slot_forces(**AL7075_CARBIDE, n_flutes=2, axial_depth=0.003, feed_per_tooth=6e-5, chip_law=3)
    assert power == pytest.approx(linear, rel=1e-12)


def test_mean_slot_forces_of_the_power_laws_are_differentiable_casadi_expressions() -> None:
    """Calibration fits the exponents through the closed form: a casadi expression, equal to the float one."""
    import casadi as ca

    m = ca.SX.sym("m", 3)
    k = dict(AL7075_CARBIDE)
    symbolic = mean_slot_forces(**k, n_flutes=2, axial_depth=0.003, feed_per_tooth=5e-5, chip_law=3,
                                mc_t=m[0], mc_r=m[1], mc_a=m[2])
    f = ca.Function("f", [m], [ca.vertcat(symbolic["Fx"], symbolic["Fy"], symbolic["Fz"])])
    exponents = (0.2, 0.45, 0.3)
    numeric = mean_slot_forces(**k, n_flutes=2, axial_depth=0.003, feed_per_tooth=5e-5, chip_law=3,
                               mc_t=exponents[0], mc_r=exponents[1], mc_a=exponents[2])
    np.testing.assert_allclose(np.array(f(exponents)).ravel(), [numeric["Fx"], numeric["Fy"], numeric["Fz"]],
                               rtol=1e-14)
    jacobian = np.array(ca.Function("j", [m], [ca.jacobian(f(m), m)])(exponents))
    assert np.all(np.isfinite(jacobian)) and abs(jacobian[0, 1]) > 0 and jacobian[0, 0] == 0


def test_start_angle_is_the_spindle_phase() -> None:
    """Flute 0 at start_angle + the angle state: shifting one or the other gives the same forces."""
    base = {"n_flutes": 2, "spindle_speed": OMEGA, "feed_velocity_x": 0.02, "helix_angle": 0.5,
            "runout_offset": 1e-5}
    angles = np.linspace(0, TWO_PI, 50, endpoint=False)
    shifted = CUTTING_FORCE.evaluate(**base, angle=angles, start_angle=0.7)
    moved = CUTTING_FORCE.evaluate(**base, angle=(angles + 0.7) % TWO_PI)
    for name in ("Fx", "Fy", "Fz", "torque", "spindle_angle"):
        np.testing.assert_allclose(shifted[name], moved[name], rtol=1e-9, atol=1e-9, err_msg=name)


@pytest.mark.parametrize("runout_angle", [0.0, 0.3])
def test_a_runout_larger_than_the_feed_moves_the_chip_to_the_next_flute(runout_angle: float) -> None:
    """2 flutes slotting at 10 um per tooth, the tool axis 20 um off (the flutes' radii 40 um apart, times
    cos(runout_angle)): flute 1 never reaches the surface flute 0 left and cuts nothing, flute 0 cuts the feed of
    both (2 f_t sin(phi)), so over a revolution the shear forces, linear in the chip, are the runout-free ones (the
    material removed is the feed's). The chip of flute 0 is not f_t sin(phi) + 40 um: that would remove more than
    the feed."""
    shear_only = {"Kte": 0.0, "Kre": 0.0, "Kae": 0.0}
    feed_per_tooth = 10e-6
    base = {"n_flutes": 2, "spindle_speed": OMEGA, "feed_velocity_x": feed_per_tooth * 2 * OMEGA / TWO_PI,
            "axial_depth": 0.002, "helix_angle": 0.0, "entry_angle": 0.0, "exit_angle": math.pi, **shear_only}
    angles = np.linspace(0, TWO_PI, 720, endpoint=False)  # symmetric under half a turn: each flute's angles
    with_runout = CUTTING_FORCE.evaluate(**base, runout_offset=20e-6, runout_angle=runout_angle, angle=angles)
    without = CUTTING_FORCE.evaluate(**base, angle=angles)
    for name in ("Fx", "Fy", "Fz"):
        assert np.mean(with_runout[name]) == pytest.approx(np.mean(without[name]), rel=1e-9), name
    flute_1_alone = angles > math.pi  # flute 0 out of the slot (0 .. pi), flute 1 in it
    resultant = {name: np.hypot(f["Fx"], f["Fy"]) for name, f in (("with", with_runout), ("without", without))}
    assert np.all(resultant["with"][flute_1_alone] == 0) and np.all(resultant["without"][flute_1_alone][1:] > 0)
    phi = angles[~flute_1_alone][1:]  # flute 0 in the slot: its chip is both feeds
    defaults = CUTTING_FORCE.defaults()
    chip = 2 * feed_per_tooth * np.sin(phi)
    fy = base["axial_depth"] * chip * (defaults["Ktc"] * np.sin(phi) - defaults["Krc"] * np.cos(phi))
    np.testing.assert_allclose(with_runout["Fy"][~flute_1_alone][1:], fy, rtol=1e-9, atol=1e-9)


# ---- the C code specialized per flute count (ModelDefinition.specialize_on) ----


@pytest.mark.parametrize("split", [("regeneration_passes", 1), ("regeneration_passes", 4), ("Ktc", 2),
                                   ("n_flutes", 2)])
def test_a_split_of_the_copies_needs_a_fixed_int_parameter_and_a_threshold_in_its_range(split) -> None:
    import dataclasses

    with pytest.raises(ValueError, match=f"CuttingForce.{split[0]}: specialize_split needs"):
        dataclasses.replace(CUTTING_FORCE, specialize_split=split, _cache={})


@pytest.mark.parametrize("passes", CUTTING_FORCE.split_values())
def test_the_equations_specialized_per_flute_count_are_the_generic_ones(passes: int) -> None:
    """One copy per flute count and per side of regeneration_passes (one delay; several, serving every value from 2:
    model.c gives the delays beyond it the one-period value), each equal to the generic equations; the copies for
    one delay hold no terms of earlier surfaces (1,939 instructions with 2 flutes, as before multiple
    regeneration)."""
    generic = CUTTING_FORCE.function()
    names = [v.name for v in CUTTING_FORCE.arguments]
    rng = np.random.default_rng(7)
    defaults = CUTTING_FORCE.defaults()
    for n in CUTTING_FORCE.specialized_values():
        special = CUTTING_FORCE.function(n, passes)
        assert special.n_instructions() < generic.n_instructions() * (n + 0.5) / 6  # absent flutes dropped
        if passes == 1:
            assert special.n_instructions() < 0.85 * CUTTING_FORCE.function(n, MAX_PASSES).n_instructions()
        for _ in range(20):
            values = {**defaults, "n_flutes": float(n), "spindle_speed": OMEGA, "axial_depth": 0.003,
                      "feed_velocity_x": rng.uniform(-0.05, 0.05), "feed_velocity_y": rng.uniform(-0.05, 0.05),
                      "helix_angle": rng.uniform(0, 0.8), "runout_offset": rng.uniform(0, 2e-5),
                      "runout_angle": rng.uniform(0, TWO_PI), "entry_angle": rng.uniform(0, TWO_PI),
                      "exit_angle": rng.uniform(0, TWO_PI), "angle": rng.uniform(0, TWO_PI),
                      "displacement_x": rng.uniform(-1e-5, 1e-5), "delayed_displacement_y": rng.uniform(-1e-5, 1e-5)}
            delays = {f"delayed_displacement_{axis}_{k}": (values[f"delayed_displacement_{axis}"] if passes == 1
                                                           else rng.uniform(-1e-5, 1e-5))
                      for k in range(2, MAX_PASSES + 1) for axis in "xy"}
            args = [{**values, **delays}[k] for k in names]
            np.testing.assert_array_equal(np.array(special(*args), dtype=float).ravel(),
                                          np.array(generic(*args), dtype=float).ravel())


@pytest.mark.parametrize("n_flutes", range(1, 7))
def test_every_flute_count_equals_the_reference(fmu: Path, n_flutes: int) -> None:
    """The FMU runs the copy of the equations for its flute count (with helix and runout): equal to ForceReference."""
    h = 1e-5
    base = {"n_flutes": n_flutes, "spindle_speed": OMEGA, "feed_velocity_x": 0.02, "axial_depth": 0.003,
            "helix_angle": 0.5, "runout_offset": 1e-5, "runout_angle": 0.4, "exit_angle": math.pi}
    points = [{**base, "displacement_x": 1e-5 * math.sin(TWO_PI * 900 * h * k)} for k in range(300)]
    rows = []
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize(points[0])
        for point in points:
            slave.set(point, include_fixed=False)
            assert slave.step(h) == OK
            rows.append(slave.get(OUTPUTS))
    assert_close(np.array(rows), reference_trajectory(points, h), what=f"outputs with {n_flutes} flutes")


# ---- regenerative chip thickness ----

SLOT = {"n_flutes": 2, "spindle_speed": OMEGA, "feed_velocity_x": 0.02, "axial_depth": 0.003}
PERIOD = TWO_PI / (2 * OMEGA)  # tooth period, 5 ms


def _outputs_replaying_from(fmu: Path, start: dict, points: list[dict], h: float, snapshot: int) -> np.ndarray:
    """The outputs after each step through ``points`` (initialized with ``start``); the steps from ``snapshot`` on
    replayed from an FMU state taken there must give them bit for bit."""
    rows = []
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize(start)
        for k, point in enumerate(points):
            if k == snapshot:
                state = slave.fmu.getFMUState()
            slave.set(point, include_fixed=False)
            assert slave.step(h) == OK
            rows.append(slave.get(OUTPUTS))
        slave.set_state(state)
        slave.fmu.freeFMUState(state)
        replay = []
        for point in points[snapshot:]:
            slave.set(point, include_fixed=False)
            assert slave.step(h) == OK
            replay.append(slave.get(OUTPUTS))
    assert np.array_equal(np.array(replay), np.array(rows[snapshot:]))
    return np.array(rows)


def test_history_ring_and_delayed_displacement_equal_the_reference(fmu: Path) -> None:
    """A vibrating tool (x, y sinusoids at 900 Hz) for 800 steps of 10 us through a ring of 600 samples:
    the heap grows (256, 512, 600 samples), the ring wraps while the tooth period (500 samples) stays
    covered; outputs equal ForceReference. An FMU state from before the growth replays bit-identically."""
    h, steps = 1e-5, 800
    t = h * np.arange(steps)
    points = [{**SLOT, "history_size": 600, "displacement_x": 2e-5 * math.sin(TWO_PI * 900 * ti),
               "displacement_y": 1e-5 * math.cos(TWO_PI * 900 * ti + 0.3)} for ti in t]
    rows = _outputs_replaying_from(fmu, points[0], points, h, 300)
    expected = reference_trajectory(points, h)
    assert_close(rows, expected, what="outputs")
    without = reference_trajectory([{**p, "displacement_x": 0.0, "displacement_y": 0.0} for p in points], h)
    assert np.sqrt(np.mean((expected[:, 0] - without[:, 0]) ** 2)) > 0.05 * np.sqrt(np.mean(without[:, 0] ** 2))


def test_the_delayed_displacement_is_one_period_before_the_current_inputs_sample() -> None:
    """The regenerative delay is exactly T: after the step from t_k the outputs hold the inputs x(t_k), and the
    delayed displacement is x(t_k - T) (a ramp, which linear interpolation reproduces), not x(t_k + h - T); inputs
    set since the step are a sample at the current time. (The C code is held to this class to 1e-12.)"""
    h, period, c = 1e-5, 1.234e-3, 2.0
    history = DisplacementHistory(1000)
    for k in range(300):
        t = k * h
        history.record(t, h, c * t, -c * t, period, True)
        dx, dy = history.delayed(t + h, period, c * t, -c * t)  # the outputs at t + h, inputs of t
        if t > period:
            assert dx == pytest.approx(c * (t - period), rel=1e-12, abs=1e-15) and dy == pytest.approx(-dx)
        else:
            assert (dx, dy) == (0.0, 0.0)  # before the oldest sample: no regeneration yet
    now = 300 * h
    dx, _ = history.delayed(now, period, 5.0, 0.0)  # set since the last step: a sample now
    assert dx == pytest.approx(c * (now - period), rel=1e-12)


def test_a_displacement_step_changes_the_chip_for_one_tooth_period(fmu: Path) -> None:
    """The tool moves 5 um towards the feed at t0 and stays: the chip is thicker until the next flute
    cuts the surface this one leaves, one tooth period later; then the forces are those of no offset
    (a static offset is no regeneration). The outputs after a step hold the inputs at its start as the newest
    displacement sample, so the one-period window of samples [t0, t0 + T] shows in the outputs up to t0 + T + h."""
    h, steps, jump = 1e-5, 1500, 600
    rows = {}
    for offset in (0.0, 5e-6):
        out = []
        with Slave(fmu) as slave:
            slave.instantiate()
            slave.initialize(SLOT)
            for k in range(steps):
                if k == jump:
                    slave.set({"displacement_x": offset})
                assert slave.step(h) == OK
                out.append(slave.get(["Fx", "Fy", "Fz"]))
        rows[offset] = np.array(out)
    t = h * np.arange(1, steps + 1)
    t0 = jump * h
    during = (t > t0 + h) & (t < t0 + PERIOD)
    after = t > t0 + PERIOD + 1.5 * h
    assert np.array_equal(rows[0.0][t <= t0], rows[5e-6][t <= t0])
    assert np.array_equal(rows[0.0][after], rows[5e-6][after])
    change = rows[5e-6][during] - rows[0.0][during]
    assert np.all(np.sqrt(np.mean(change ** 2, axis=0)) > 0.02 * np.sqrt(np.mean(rows[0.0] ** 2, axis=0)))


def test_a_history_shorter_than_the_tooth_period_is_an_error(fmu: Path) -> None:
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize({**SLOT, "history_size": 100})
        statuses = [slave.step(1e-5) for _ in range(100)]
        assert statuses[:99] == [OK] * 99 and statuses[99] == ERROR
        message = slave.last_error()
        assert message.startswith("doStep: t = 0.00099 s: the displacement history"), message
        for part in ("history_size = 100 samples", "shorter than one tooth period 2*pi/(n_flutes*spindle_speed) = "
                     "0.005 s", "n_flutes = 2", "spindle_speed = 628.319 rad/s", "set history_size to at least 502"):
            assert part in message, message


def test_a_history_shorter_than_the_regeneration_passes_is_an_error(fmu: Path) -> None:
    """Multiple regeneration looks regeneration_passes tooth periods back: the ring must span them all."""
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize({**SLOT, "history_size": 800, "regeneration_passes": 2})
        statuses = [slave.step(1e-5) for _ in range(800)]
        assert statuses[:799] == [OK] * 799 and statuses[799] == ERROR
        message = slave.last_error()
        for part in ("history_size = 800 samples", "shorter than 2 tooth periods (regeneration_passes) of "
                     "2*pi/(n_flutes*spindle_speed) = 0.005 s", "set history_size to at least 1002"):
            assert part in message, message


@pytest.mark.parametrize("passes", [2, 3])
def test_multiple_regeneration_equals_the_reference(fmu: Path, passes: int) -> None:
    """regeneration_passes = P: the chip is the thinnest of the surfaces the last P flutes left. A tool vibrating
    by 60 um at 700 Hz (more than the 50 um feed per tooth: flutes leave the cut) through a ring that wraps; the
    outputs equal ForceReference's, an FMU state replays bit-identically, and they differ from one delay alone
    where a flute follows one that left the cut."""
    h, steps = 1e-5, 2500
    point = {**SLOT, "spindle_speed": 2 * OMEGA, "feed_velocity_x": 0.04, "history_size": 1200}  # T = 2.5 ms
    t = h * np.arange(steps)
    points = [{**point, "displacement_x": 6e-5 * math.sin(TWO_PI * 700 * ti),
               "displacement_y": 4e-5 * math.cos(TWO_PI * 700 * ti + 0.3)} for ti in t]
    rows = _outputs_replaying_from(fmu, {**points[0], "regeneration_passes": passes}, points, h, 1500)
    expected = reference_trajectory([{**p, "regeneration_passes": passes} for p in points], h)
    assert_close(rows, expected, what="outputs")
    single = reference_trajectory(points, h)
    late = t > passes * 2.5e-3  # once the history reaches P periods back
    assert np.sqrt(np.mean((expected[late, 0] - single[late, 0]) ** 2)) > 0.05 * np.sqrt(np.mean(single[late, 0] ** 2))


def test_a_stopped_spindle_feeding_into_the_cut_warns_once_and_cuts_nothing(fmu: Path) -> None:
    with Slave(fmu) as slave:
        slave.instantiate()
        slave.initialize({**SLOT, "spindle_speed": 0.5})
        assert slave.step(1e-3) == WARNING
        assert slave.step(1e-3) == OK
        assert slave.get(["Fx", "Fy", "Fz", "torque", "power", "feed_per_tooth"]).tolist() == [0.0] * 6
        assert len(slave.warnings()) == 1
        assert "spindle_speed = 0.5 rad/s is below 1 rad/s (stopped) while the tool feeds at 0.02 m/s into the cut " \
               "(axial_depth = 0.003 m): no chip, the forces are 0 (reported once)" in slave.warnings()[0]


# ---- the force/vibration loop through the orchestrator ----

LOOP_TOML = """\
[scenario]
name = "{name}"
stop_time = {stop}
output_interval = 1e-5
[fmus.force]
fmu = "CuttingForce"
fmi = {fmi}
step_size = {h}
[fmus.force.parameters]
n_flutes = 2
[fmus.force.inputs]
spindle_speed = {{ value = 6000.0, unit = "rpm" }}
feed_velocity_x = {{ value = 1200.0, unit = "mm/min" }}
axial_depth = {depth}
"""
VIBRATION_TOML = """\
[fmus.vibration]
fmu = "ToolVibration"
fmi = {fmi}
step_size = {h}
[fmus.vibration.parameters]
n_modes_x = 1
n_modes_y = 1
frequency_x1 = {f}
frequency_y1 = {f}
damping_x1 = {zeta}
damping_y1 = {zeta}
stiffness_x1 = {k}
stiffness_y1 = {k}
[[connections]]
from = "force.Fx"
to = "vibration.force_x"
[[connections]]
from = "force.Fy"
to = "vibration.force_y"
[[connections]]
from = "vibration.tip_displacement_x"
to = "force.displacement_x"
delay = true
[[connections]]
from = "vibration.tip_displacement_y"
to = "force.displacement_y"
delay = true
[outputs]
record = ["force.Fx", "force.Fy", "force.Fz", "vibration.tip_displacement_x", "vibration.tip_displacement_y"]
"""
MODE = {"f": 922.0, "zeta": 0.011, "k": 1.34e6}  # Altintas' single-mode tool (Manufacturing Automation, ch. 3)


def stability_limit(rpm: float, n_flutes: int, f: float, zeta: float, k: float, Ktc: float, Krc: float) -> float:
    """Altintas' zeroth-order critical axial depth of slotting at ``rpm`` for a tool with the same
    single mode in x and y (models.stability, the lobes users get)."""
    mode = Mode(f, zeta, k)
    return float(stability_lobes((mode,), (mode,), Ktc, Krc, n_flutes, lobes=60).limit(rpm)[0])


def run_loop(tmp_path: Path, fmi: int, depth: float, h: float, stop: float, vibration: bool = True):
    """Slotting at 6000 rpm, 0.1 mm per tooth, through the orchestrator: the force FMU alone or in a
    loop with ToolVibration (force -> vibration, displacement -> force one step delayed)."""
    from milling_twin.orchestrator.master import run
    from milling_twin.orchestrator.results import load_results
    from milling_twin.orchestrator.scenario import load_scenario

    name = f"loop{int(vibration)}_fmi{fmi}_{depth:.3g}_{h:g}".replace(".", "p").replace("-", "m")
    path = tmp_path / f"{name}.toml"
    text = LOOP_TOML + (VIBRATION_TOML if vibration else '[outputs]\nrecord = ["force.Fx", "force.Fy", "force.Fz"]\n')
    path.write_text(text.format(name=name, stop=stop, fmi=fmi, h=h, depth=depth, **MODE))
    result = run(load_scenario(path, fmu_dir()), tmp_path / "runs", progress=False)
    assert result.status == "completed"
    return load_results(result.run_dir)


FMI_VERSIONS = [pytest.param(3, id="fmi3"), pytest.param(2, id="fmi2")]


@pytest.fixture(scope="module")
def critical_depth() -> float:
    return stability_limit(RPM, 2, MODE["f"], MODE["zeta"], MODE["k"], AL7075_CARBIDE["Ktc"], AL7075_CARBIDE["Krc"])


@pytest.mark.parametrize("fmi", FMI_VERSIONS)
def test_chatter_sets_in_at_altintas_stability_limit(tmp_path: Path, fmi: int, critical_depth: float) -> None:
    """Slotting at 6000 rpm with the flexible single-mode tool: the vibration settles at 0.8 of the
    zeroth-order critical depth (0.040 mm here) and grows at 1.3 of it."""
    assert critical_depth == pytest.approx(3.98e-5, rel=0.01)
    require_fmu(fmu_dir() / ("ToolVibration.fmu" if fmi == 3 else "ToolVibration_fmi2.fmu"))
    growth = {}
    for factor in (0.8, 1.3):
        results = run_loop(tmp_path, fmi, factor * critical_depth, 1e-5, 0.2)
        t, x = results["time"].to_numpy(), results["vibration.tip_displacement_x"].to_numpy()
        window = [np.ptp(x[(t >= s) & (t < s + 0.05)]) for s in (0.1, 0.15)]
        growth[factor] = window[1] / window[0]
    assert growth[0.8] < 1.01, growth
    assert growth[1.3] > 1.5, growth


@pytest.mark.parametrize("fmi", FMI_VERSIONS)
def test_halving_the_step_changes_the_force_waveform_by_less_than_one_percent(
        tmp_path: Path, fmi: int, critical_depth: float) -> None:
    """At the recommended step of 10 us: the force/vibration loop (one-step delay on the displacement) at
    0.75 of the critical depth, where regeneration matters, and the force alone in a 3 mm slot."""
    require_fmu(fmu_dir() / ("ToolVibration.fmu" if fmi == 3 else "ToolVibration_fmi2.fmu"))
    for depth, vibration, tolerance in ((0.75 * critical_depth, True, 0.01), (0.003, False, 1e-9)):
        coarse = run_loop(tmp_path, fmi, depth, 1e-5, 0.2, vibration)
        fine = run_loop(tmp_path, fmi, depth, 5e-6, 0.2, vibration)
        assert np.allclose(coarse["time"], fine["time"], rtol=0, atol=1e-12)
        for axis in ("Fx", "Fy", "Fz"):
            a, b = coarse[f"force.{axis}"].to_numpy(), fine[f"force.{axis}"].to_numpy()
            change = np.sqrt(np.mean((a - b) ** 2)) / np.sqrt(np.mean(b ** 2))
            print(f"depth {depth * 1e3:.3g} mm, vibration {vibration}, {axis}: halving the step changes it by {100 * change:.3g} % RMS")
            assert change < tolerance, (depth, axis, change)
