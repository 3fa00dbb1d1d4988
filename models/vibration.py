"""Modal vibration of the tool: modal superposition per direction, discretized exactly.

The response at the tool tip and at a second point (a sensor on the spindle housing) to the
cutting force at the tip is the sum over modes of mode-shape products times the modal response.
Per direction d in {x, y} and mode i (up to ``MAX_MODES``, ``n_modes_d`` of them active), with the
mode shape normalised to 1 at the tip so that ``k_di`` is the modal stiffness seen at the tip:

    q'' + 2 zeta wn q' + wn^2 q = wn^2 F_d / k_di,     wn = 2 pi f_di,
    tip response = sum_i q_i,   sensor response = sum_i phi_sensor_di * q_i.

Over a step of size h the force is held constant (a co-simulation step), and the update is the
exact solution of the damped oscillator for that force, so any step size is stable and exact
for piecewise-constant force (``update`` below; generated into the FMU's C code).
"""
from __future__ import annotations

import math
from typing import Mapping

import casadi as ca

from milling_twin.models.definition import ModelDefinition, State, Variable

MAX_MODES = 4
DIRECTIONS = ("x", "y")

# The single-mode tool of Altintas' chatter examples (Manufacturing Automation, 2nd ed., Ch. 3):
# 922 Hz, damping ratio 0.011, modal stiffness 1.34e6 N/m, the same in x and y.
DEFAULT_MODES = ((922.0, 0.011, 1.34e6, 0.2), (2400.0, 0.02, 8.0e6, -0.4),
                 (4100.0, 0.03, 2.0e7, 0.3), (6300.0, 0.03, 5.0e7, 0.1))


# m: a mode whose deviation from its static deflection is below this (and its velocity below REST x omega_n) is at
# rest there: its state is set to it exactly. Left alone, a free response decays into subnormal numbers whose
# rounding never reaches zero, and differs with the step size; a tool entering the cut again then carries
# 1e-322 m of different "vibration", enough to switch a flute's edge force on where the chip is otherwise zero
# (a plunge), which seeds chatter differently in runs stepped differently. 1e-30 m is 24 orders of magnitude
# below a cut's vibration and 8 below the rounding of a deflection of 1 um: it changes nothing in a cut.
REST = 1e-30


def mode_names(direction: str, i: int) -> dict[str, str]:
    n = i + 1
    return {"f": f"frequency_{direction}{n}", "zeta": f"damping_{direction}{n}",
            "k": f"stiffness_{direction}{n}", "phi": f"shape_sensor_{direction}{n}",
            "q": f"q_{direction}{n}", "v": f"v_{direction}{n}"}


def _mode_terms(v: Mapping[str, ca.SX], direction: str, i: int) -> tuple[ca.SX, ca.SX, ca.SX, ca.SX]:
    """(active, natural angular frequency, damping ratio, static displacement of the held force)."""
    names = mode_names(direction, i)
    active = v[f"n_modes_{direction}"] > i
    wn = 2 * math.pi * v[names["f"]]
    static = v[f"force_{direction}"] / v[names["k"]]
    return active, wn, v[names["zeta"]], static


def equations(v: Mapping[str, ca.SX]) -> dict[str, ca.SX]:
    out: dict[str, ca.SX] = {}
    for d in DIRECTIONS:
        tip = {"displacement": 0, "velocity": 0, "acceleration": 0}
        sensor = dict(tip)
        for i in range(MAX_MODES):
            names = mode_names(d, i)
            active, wn, zeta, static = _mode_terms(v, d, i)
            q, qd = v[names["q"]], v[names["v"]]
            response = {"displacement": q, "velocity": qd,
                        "acceleration": wn ** 2 * (static - q) - 2 * zeta * wn * qd}
            for key, value in response.items():
                tip[key] = tip[key] + ca.if_else(active, value, 0)
                sensor[key] = sensor[key] + ca.if_else(active, v[names["phi"]] * value, 0)
        for key in tip:
            out[f"tip_{key}_{d}"] = tip[key]
            out[f"sensor_{key}_{d}"] = sensor[key]
    return out


def update(v: Mapping[str, ca.SX], h: ca.SX) -> dict[str, ca.SX]:
    """Exact damped-oscillator solution over h for the force held at its current value."""
    new: dict[str, ca.SX] = {}
    for d in DIRECTIONS:
        for i in range(MAX_MODES):
            names = mode_names(d, i)
            active, wn, zeta, static = _mode_terms(v, d, i)
            e0, v0 = v[names["q"]] - static, v[names["v"]]
            root = ca.sqrt(1 - zeta ** 2)
            wd = wn * root
            decay = ca.exp(-zeta * wn * h)
            c, s = ca.cos(wd * h), ca.sin(wd * h)
            e1 = decay * (e0 * c + (v0 + zeta * wn * e0) / wd * s)
            v1 = decay * (v0 * c - (wn * e0 + zeta * v0) / root * s)
            # A free response rung down below REST is the static deflection exactly (see REST)
            resting = ca.logic_and(ca.fabs(e1) < REST, ca.fabs(v1) < REST * wn)
            e1, v1 = ca.if_else(resting, 0, e1), ca.if_else(resting, 0, v1)
            new[names["q"]] = ca.if_else(active, static + e1, 0)
            new[names["v"]] = ca.if_else(active, v1, 0)
    return new


def _variables() -> tuple[Variable, ...]:
    variables: list[Variable] = []
    for d in DIRECTIONS:
        variables.append(Variable(f"n_modes_{d}", "Int32", "parameter",
                                  f"Number of active modes in {d} (a mode switched on starts at rest)",
                                  start=1, min=0, max=MAX_MODES))
        for i, (f, zeta, k, phi) in enumerate(DEFAULT_MODES):
            names, n = mode_names(d, i), i + 1
            variables += [
                Variable(names["f"], "Float64", "parameter", f"Natural frequency of mode {n} in {d}",
                         unit="Hz", start=f, min=1.0, max=5e4),
                Variable(names["zeta"], "Float64", "parameter", f"Damping ratio of mode {n} in {d}",
                         start=zeta, min=1e-4, max=0.95),
                Variable(names["k"], "Float64", "parameter", f"Modal stiffness of mode {n} in {d} at the tool tip",
                         unit="N/m", display_unit="N/um", start=k, min=1e3, max=1e11),
                Variable(names["phi"], "Float64", "parameter",
                         f"Mode shape of mode {n} in {d} at the sensor point (1 at the tool tip)",
                         start=phi, min=-100.0, max=100.0),
            ]
    for d in DIRECTIONS:
        variables.append(Variable(f"force_{d}", "Float64", "input", f"Cutting force on the tool tip in {d}",
                                  unit="N", start=0.0, min=-1e6, max=1e6))
    display = {"displacement": ("m", "um"), "velocity": ("m/s", "mm/s"), "acceleration": ("m/s2", "")}
    for point in ("tip", "sensor"):
        for d in DIRECTIONS:
            for key, (unit, shown) in display.items():
                variables.append(Variable(f"{point}_{key}_{d}", "Float64", "output",
                                          f"{key.capitalize()} of the {'tool tip' if point == 'tip' else 'sensor point'}"
                                          f" in {d}", unit=unit, display_unit=shown))
    return tuple(variables)


def _states() -> tuple[State, ...]:
    return tuple(
        State(mode_names(d, i)[kind], f"Modal {'displacement' if kind == 'q' else 'velocity'} of mode {i + 1} in {d}",
              unit="m" if kind == "q" else "m/s")
        for d in DIRECTIONS for i in range(MAX_MODES) for kind in ("q", "v"))


VIBRATION = ModelDefinition(
    identifier="ToolVibration",
    description="Modal tool vibration: up to 4 modes per direction, exact discretization, tip and sensor response",
    default_step_size=1e-5,
    default_stop_time=0.1,
    equations=equations,
    update=update,
    states=_states(),
    variables=_variables(),
)
