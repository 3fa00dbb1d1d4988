"""Mechanistic milling force of a flat end mill (Altintas' linear edge-force model), with
helix lag, runout and regenerative chip thickness.

Conventions (Altintas, *Manufacturing Automation*, 2nd ed., Cambridge University Press 2012, ch. 2.4):

* Machine frame x, y, z; z along the tool axis towards the spindle. The spindle turns clockwise seen
  from the spindle (M3). The immersion angle ``phi`` of a cutting-edge point is measured clockwise
  from +y, so with the feed along +x the edge is at the front of the tool at ``phi = pi/2`` and the
  chip thickness is ``f_t*sin(phi)`` (up-milling from ``phi = 0``, slotting is ``0 .. pi``).
* Any feed direction: the static chip is ``T_tooth*(v_x*sin(phi) + v_y*cos(phi))`` (the feed per
  tooth projected on the edge's radial direction, ``T_tooth = 2*pi/(N*omega)``), which is
  ``f_t*sin(phi + theta_feed)`` with ``theta_feed = atan2(v_y, v_x)``. The engagement window
  ``entry_angle .. exit_angle`` is given **relative to the feed direction** (Altintas' angles with
  the feed along +x): an edge point cuts where ``phi + theta_feed`` lies clockwise from entry to
  exit, both taken modulo 2*pi (entry = exit: no engagement). Slotting is always ``0 .. pi``,
  down-milling a half-immersion cut ``pi/2 .. pi``, up-milling ``0 .. pi/2``.
* Edge point of flute j (0 .. N-1) at height z above the tool tip (z in 0 .. axial_depth):
  ``phi = angle + j*2*pi/N - z*tan(helix)/R``, a right-hand helix lagging behind the tip; ``angle``
  is the spindle angle (a state advanced by ``omega*h`` each step, output as ``spindle_angle``).
* Chip thickness: ``h = max(0, min over k = 1..N of (k*static + r_j - r_(j-k)) + dx*sin(phi) +
  dy*cos(phi))`` with ``r_j = runout_offset*cos(runout_angle - j*2*pi/N)`` the radius change of
  flute j from an offset tool axis (Altintas' runout model, ch. 2.6: the surface in front of flute j
  is the innermost one the flutes before it left, so a flute the runout holds back by more than the
  feed cuts nothing and the next one cuts both feeds; without runout the minimum is ``static``) and
  ``dx, dy`` the tool displacement now minus one tooth period ago (regeneration: the surface the
  previous flute left).
* Multiple regeneration (``regeneration_passes = P > 1``): ``h = min(h above, min over k = 2..P of
  (k*max(static, 0) + r_j - r_(j-k) + dx_k*sin(phi) + dy_k*cos(phi)))`` with ``dx_k, dy_k`` the displacement
  now minus k tooth periods ago: where chatter has thrown the flutes before out of the cut, the surface in
  front of this one is the innermost of those the last P flutes left (Tlusty; Altintas 2012, ch. 3.6),
  not the one the previous flute would have left had it cut. With one delay only (P = 1, the default:
  the delay equation of the stability theory) the chip of a flute after one that left the cut counts
  material that is not there, and strong chatter grows without bound; with P > 1 it settles into a
  limit cycle. Where the vibration repeats every tooth period, P changes nothing (docs/models.md: why
  whole parts still default to 1).
* Element forces on the tool over a slice of height dz, only where h > 0 inside the window:
  ``dFt = Ktc*h*dz + Kte*dz``, ``dFr = Krc*h*dz + Kre*dz``, ``dFa = Kac*h*dz + Kae*dz``, projected
  ``dFx = -dFt*cos(phi) - dFr*sin(phi)``, ``dFy = dFt*sin(phi) - dFr*cos(phi)``, ``dFz = dFa``.
  ``Fx, Fy, Fz`` are the force **on the tool** (what the vibration FMU takes as its input); a
  dynamometer under the workpiece measures the reaction, ``-F``, in its own axes.
* ``torque = sum(dFt*(R + r_j))`` is the cutting torque the spindle supplies, ``power = torque*omega``.

The tool is discretized into ``AXIAL_SLICES`` slices of equal height and ``MAX_FLUTES`` flutes, of
which the first ``n_flutes`` are active; the expression graph is generated into the FMU's C code.
Below ``OMEGA_MIN`` the spindle counts as stopped: there is no chip and all forces are 0.

The delayed displacements (one tooth period ago) come from a history of the displacement inputs
kept by the FMU's C code (``fmus/force/model.c``): they are the model's ``native_states``.
:class:`ForceReference` below is the reference implementation the tests hold the C code to.
"""
from __future__ import annotations

import bisect
import math
from collections import deque
from typing import Mapping, Sequence

import casadi as ca
import numpy as np

from milling_twin.models.definition import ModelDefinition, State, Variable
from milling_twin.models.step_clock import StepClock

AXIAL_SLICES = 16
MAX_FLUTES = 6
MAX_PASSES = 3  # regeneration_passes at most (<= MAX_FLUTES: the runout terms r_j - r_(j-k) are defined up to it)
OMEGA_MIN = 1.0  # rad/s (9.5 rpm): below it the spindle counts as stopped
TWO_PI = 2.0 * math.pi
# The chip-thickness laws (parameter chip_law, see element_force) and the reference chip thickness of laws 2 and 3.
CHIP_LAW_LINEAR, CHIP_LAW_EXPONENTIAL, CHIP_LAW_POWER_EDGE = 1, 2, 3
CHIP_LAWS = {"linear": CHIP_LAW_LINEAR, "exponential": CHIP_LAW_EXPONENTIAL, "power_edge": CHIP_LAW_POWER_EDGE}
CHIP_REFERENCE = 1e-3  # m: h0, Kienzle's k_c1.1 is the specific force at a 1 mm chip
CHIP_MIN = 1e-12  # m: the power law's chip thickness is at least this (only elements with h > 0 cut)

# Al7075-T6 with a cemented-carbide end mill, dry: the row "[190]" of Table 5 in
# "Milling Force Model for Aviation Aluminum Alloy: Academic Insight and Perspective Analysis",
# Chinese Journal of Mechanical Engineering 34 (2021), doi:10.1186/s10033-021-00536-9
# (Ktc 767.01 N/mm2, Kte 27.7 N/mm, Krc 168.8 N/mm2, Kre 26.6 N/mm, Kac 222 N/mm2, Kae 0.7 N/mm).
AL7075_CARBIDE = {"Ktc": 767.01e6, "Krc": 168.8e6, "Kac": 222.0e6, "Kte": 27.7e3, "Kre": 26.6e3, "Kae": 0.7e3}


def _tooth_period(v: Mapping[str, ca.SX]) -> tuple[ca.SX, ca.SX]:
    """(spindle turning, tooth period) with the period finite however slow the spindle."""
    turning = v["spindle_speed"] >= OMEGA_MIN
    return turning, TWO_PI / (v["n_flutes"] * ca.fmax(v["spindle_speed"], OMEGA_MIN))


def _wrap(angle: ca.SX) -> ca.SX:
    """angle modulo 2*pi, in [0, 2*pi)."""
    return angle - TWO_PI * ca.floor(angle / TWO_PI)


def element_force(v: Mapping[str, ca.SX], h: ca.SX, direction: str) -> ca.SX:
    """Force per unit width of cut on an edge element with chip thickness ``h > 0`` in one direction
    (``t`` tangential, ``r`` radial, ``a`` axial), by the parameter ``chip_law``:

    1 (linear, Altintas): ``K_c*h + K_e``;
    2 (exponential, Kienzle): ``K_c*h0*(h/h0)**(1 - m_c)`` with ``K_c`` the specific force at the reference chip
      thickness ``h0`` (Kienzle's k_c1.1) and no edge term;
    3 (power with edge): ``K_c*h0*(h/h0)**(1 - m_c) + K_e``, which is law 1 at ``m_c = 0`` and law 2 at ``K_e = 0``.

    The size-effect factor ``(h/h0)**(-m_c)`` is 1 under law 1 (no power is computed there: the C code has its own
    copies of the equations for law 1, see ``specialize_fixed``)."""
    law = v["chip_law"]
    size_effect = (ca.fmax(h, CHIP_MIN) / CHIP_REFERENCE) ** (-v[f"mc_{direction}"])
    edge = ca.if_else(law == CHIP_LAW_EXPONENTIAL, 0, v[f"K{direction}e"])
    return v[f"K{direction}c"] * h * ca.if_else(law == CHIP_LAW_LINEAR, 1, size_effect) + edge


def _runout_chip(n_flutes: ca.SX, static: ca.SX, runout: Mapping[int, ca.SX]) -> ca.SX:
    """The chip a flute cuts from the feed and the runout: ``min over back = 1..n_flutes of (back*static +
    r_j - r_(j-back))`` (Kline and DeVor 1983; Altintas 2012, ch. 2.6), ``static`` the feed per tooth projected on
    the edge's radial direction, ``runout[back]`` = ``r_j - r_(j-back)``. The material in front of flute j is what
    every flute before it left: a flute that the runout holds back by more than the feed cuts
    nothing, and the next one cuts the feed of both, so the material removed per revolution is the feed's whatever
    the runout. Without runout and with ``static >= 0`` it is ``static`` exactly (back = 1)."""
    chip = static + runout[1]
    for back in range(2, MAX_FLUTES + 1):
        chip = ca.if_else(n_flutes >= back, ca.fmin(chip, back * static + runout[back]), chip)
    return chip


def equations(v: Mapping[str, ca.SX]) -> dict[str, ca.SX]:
    turning, period = _tooth_period(v)
    vx, vy = v["feed_velocity_x"], v["feed_velocity_y"]
    feed_angle = ca.atan2(vy, vx)
    radius = v["tool_diameter"] / 2
    lag_per_height = ca.tan(v["helix_angle"]) / radius
    dz = v["axial_depth"] / AXIAL_SLICES
    width = _wrap(v["exit_angle"] - v["entry_angle"])
    dx = v["displacement_x"] - v["delayed_displacement_x"]
    dy = v["displacement_y"] - v["delayed_displacement_y"]
    # multiple regeneration: the displacement now minus k tooth periods ago, k = 2..MAX_PASSES; none in the C copies
    # for one delay (regeneration_passes folded in as 1: specialize_split), which then cost what they did before it
    passes = v["regeneration_passes"]
    one_delay = passes.is_constant() and float(passes) < 2
    earlier = {} if one_delay else {
        k: (v["displacement_x"] - v[f"delayed_displacement_x_{k}"], v["displacement_y"] - v[f"delayed_displacement_y_{k}"])
        for k in range(2, MAX_PASSES + 1)}
    pitch = TWO_PI / v["n_flutes"]
    # sin/cos of the MAX_FLUTES*AXIAL_SLICES edge angles by rotations (angle-addition formulas), from
    # those of the lowest slice of flute 0, of the helix lag between slices and of the flute pitches:
    # 2 + MAX_FLUTES sin/cos pairs instead of 96 (within a few ulps of sin(phi), cos(phi); exact
    # without helix for flute 0). Likewise the runout cosines cos(runout_angle - j*pitch).
    lag = [(k + 0.5) * dz * lag_per_height for k in range(AXIAL_SLICES)]
    angle = v["angle"] + v["start_angle"]  # flute 0 at the tool tip
    slice_sin, slice_cos = [ca.sin(angle - lag[0])], [ca.cos(angle - lag[0])]
    step_sin, step_cos = ca.sin(dz * lag_per_height), ca.cos(dz * lag_per_height)
    for k in range(1, AXIAL_SLICES):  # one slice higher: the edge lags by dz*lag_per_height more
        slice_sin.append(slice_sin[-1] * step_cos - slice_cos[-1] * step_sin)
        slice_cos.append(slice_cos[-1] * step_cos + slice_sin[-2] * step_sin)
    runout_sin0, runout_cos0 = ca.sin(v["runout_angle"]), ca.cos(v["runout_angle"])
    runout_cos = {j: runout_cos0 * ca.cos(j * pitch) + runout_sin0 * ca.sin(j * pitch)
                  for j in range(-MAX_FLUTES, MAX_FLUTES)}
    fx = fy = fz = torque = 0
    for j in range(MAX_FLUTES):
        active = v["n_flutes"] > j
        # r_j - r_(j-back): how much further out flute j reaches than the flute `back` teeth before it
        runout = {back: v["runout_offset"] * (runout_cos[j] - runout_cos[j - back])
                  for back in range(1, MAX_FLUTES + 1)}
        flute_radius = radius + v["runout_offset"] * runout_cos[j]
        pitch_sin, pitch_cos = ca.sin(j * pitch), ca.cos(j * pitch)
        for k in range(AXIAL_SLICES):
            phi = angle + j * pitch - lag[k]
            if j == 0:
                s, c = slice_sin[k], slice_cos[k]
            else:
                s = slice_sin[k] * pitch_cos + slice_cos[k] * pitch_sin
                c = slice_cos[k] * pitch_cos - slice_sin[k] * pitch_sin
            static = period * (vx * s + vy * c)
            h = _runout_chip(v["n_flutes"], static, runout) + dx * s + dy * c
            # the surfaces k = 2.. periods back (model.c gives k > regeneration_passes the delay of k = 1, which
            # makes them no thinner than h: the same terms, or larger by (k - n_flutes)*static >= 0, so that one
            # copy serves every regeneration_passes >= 2)
            advance = ca.fmax(static, 0)
            for k, (dxk, dyk) in earlier.items():
                thinner = k * advance + runout[k] + dxk * s + dyk * c
                h = ca.if_else(thinner < h, thinner, h)  # a select, inlined (fmin is a call into libm)
            engaged = _wrap(phi + feed_angle - v["entry_angle"]) < width
            cutting = ca.logic_and(ca.logic_and(active, turning), ca.logic_and(engaged, h > 0))
            ft, fr, fa = (ca.if_else(cutting, element_force(v, h, direction) * dz, 0) for direction in "tra")
            fx = fx - ft * c - fr * s
            fy = fy + ft * s - fr * c
            fz = fz + fa
            torque = torque + ft * flute_radius
    speed = ca.if_else(turning, v["spindle_speed"], 0)
    return {
        "Fx": fx, "Fy": fy, "Fz": fz, "torque": torque, "power": torque * speed,
        "spindle_angle": _wrap(angle),
        "feed_per_tooth": ca.if_else(turning, period * ca.sqrt(vx ** 2 + vy ** 2), 0),
    }


def update(v: Mapping[str, ca.SX], h: ca.SX) -> dict[str, ca.SX]:
    """The spindle turns at the held speed over the step; the angle stays in [0, 2*pi)."""
    return {"angle": _wrap(v["angle"] + v["spindle_speed"] * h)}


def _deg(x: float) -> float:
    return math.radians(x)


# the native states model.c fills from the displacement history, (name, axis, tooth periods ago), k = 1..MAX_PASSES
DELAYED = tuple((f"delayed_displacement_{axis}" + ("" if k == 1 else f"_{k}"), axis, k)
                for k in range(1, MAX_PASSES + 1) for axis in "xy")
DELAYED_STATES = tuple(name for name, _, _ in DELAYED)


CUTTING_FORCE = ModelDefinition(
    identifier="CuttingForce",
    description="Mechanistic milling force of a flat end mill: edge-force model, helix, runout, regenerative chip",
    default_step_size=1e-5,
    default_stop_time=0.1,
    equations=equations,
    update=update,
    native_states=DELAYED_STATES,
    # model.c interpolates the history k periods T = 2 pi/(N omega) before the current displacement's sample (the
    # newest sample when the inputs equal it, else now: DisplacementHistory); before the first step there is no
    # history and the delayed displacement is the current one
    native_dependencies=tuple((name, ("n_flutes", "spindle_speed", f"displacement_{axis}"))
                              for name, axis, _ in DELAYED),
    native_initial_states=tuple((name, f"displacement_{axis}") for name, axis, _ in DELAYED),
    specialize_on="n_flutes",  # C code per flute count: absent flutes cost nothing
    specialize_fixed=(("chip_law", CHIP_LAW_LINEAR),),  # ... for the linear law (no powers); the others run generic
    specialize_split=("regeneration_passes", 2),  # ... each for one delay and for several (model.c: the rest inert)
    constants=(("OMEGA_MIN", OMEGA_MIN), ("TWO_PI", TWO_PI), ("MAX_PASSES", MAX_PASSES)),  # model.c
    states=(
        State("angle", "Spindle angle: flute 0 at the tool tip, clockwise from +y", unit="rad"),
        State("delayed_displacement_x", "Tool displacement in x one tooth period ago (model.c)", unit="m"),
        State("delayed_displacement_y", "Tool displacement in y one tooth period ago (model.c)", unit="m"),
        *(State(f"delayed_displacement_{axis}_{k}",
                f"Tool displacement in {axis} {k} tooth periods ago (model.c; regeneration_passes >= {k})", unit="m")
          for k in range(2, MAX_PASSES + 1) for axis in "xy"),
    ),
    variables=(
        Variable("chip_law", "Int32", "parameter",
                 "Chip-thickness law: 1 linear K_c*h + K_e (Altintas), 2 exponential K_c*h0*(h/h0)^(1-m_c) "
                 "(Kienzle, h0 = 1 mm, no edge term), 3 the power law plus the edge term K_e",
                 start=CHIP_LAW_LINEAR, min=CHIP_LAW_LINEAR, max=CHIP_LAW_POWER_EDGE),
        Variable("Ktc", "Float64", "parameter",
                 "Tangential cutting coefficient (laws 2 and 3: the specific force at h0 = 1 mm, k_c1.1)",
                 unit="N/m2", display_unit="N/mm2", start=AL7075_CARBIDE["Ktc"], min=0.0, max=1e10),
        Variable("Krc", "Float64", "parameter", "Radial cutting coefficient (laws 2 and 3: at h0 = 1 mm)",
                 unit="N/m2", display_unit="N/mm2", start=AL7075_CARBIDE["Krc"], min=-1e10, max=1e10),
        Variable("Kac", "Float64", "parameter",
                 "Axial cutting coefficient, force on the tool along +z (laws 2 and 3: at h0 = 1 mm)",
                 unit="N/m2", display_unit="N/mm2", start=AL7075_CARBIDE["Kac"], min=-1e10, max=1e10),
        Variable("mc_t", "Float64", "parameter", "Chip-thickness exponent m_c of the tangential force (laws 2, 3)",
                 unit="1", start=0.0, min=-1.0, max=0.99),
        Variable("mc_r", "Float64", "parameter", "Chip-thickness exponent m_c of the radial force (laws 2, 3)",
                 unit="1", start=0.0, min=-1.0, max=0.99),
        Variable("mc_a", "Float64", "parameter", "Chip-thickness exponent m_c of the axial force (laws 2, 3)",
                 unit="1", start=0.0, min=-1.0, max=0.99),
        Variable("Kte", "Float64", "parameter", "Tangential edge coefficient", unit="N/m",
                 display_unit="N/mm", start=AL7075_CARBIDE["Kte"], min=0.0, max=1e6),
        Variable("Kre", "Float64", "parameter", "Radial edge coefficient", unit="N/m",
                 display_unit="N/mm", start=AL7075_CARBIDE["Kre"], min=-1e6, max=1e6),
        Variable("Kae", "Float64", "parameter", "Axial edge coefficient", unit="N/m",
                 display_unit="N/mm", start=AL7075_CARBIDE["Kae"], min=-1e6, max=1e6),
        Variable("tool_diameter", "Float64", "parameter", "Tool diameter", unit="m", display_unit="mm",
                 start=0.01, min=1e-4, max=0.5),
        Variable("helix_angle", "Float64", "parameter", "Helix angle of the flutes (right-hand)", unit="rad",
                 display_unit="deg", start=_deg(30.0), min=0.0, max=_deg(80.0)),
        Variable("n_flutes", "Int32", "parameter", f"Number of flutes (1 .. {MAX_FLUTES}), evenly spaced",
                 start=2, min=1, max=MAX_FLUTES),
        Variable("runout_offset", "Float64", "parameter", "Radial offset of the tool axis (runout)",
                 unit="m", display_unit="um", start=0.0, min=0.0, max=1e-3),
        Variable("runout_angle", "Float64", "parameter",
                 "Direction of the runout offset: flute j's radius is R + offset*cos(angle - j*2*pi/N)",
                 unit="rad", display_unit="deg", start=0.0, min=-TWO_PI, max=TWO_PI),
        Variable("start_angle", "Float64", "parameter",
                 "Angle of flute 0 at the tool tip when the spindle angle state is 0 (the spindle phase at the "
                 "start, clockwise from +y)", unit="rad", display_unit="deg", start=0.0, min=-TWO_PI, max=TWO_PI),
        Variable("regeneration_passes", "Int32", "parameter",
                 "Tooth periods the regenerative chip looks back: 1 the delay equation of the stability theory; "
                 f"2 .. {MAX_PASSES}: the surface is the innermost the last flutes left, so that chatter settles "
                 "into a limit cycle where flutes leave the cut",
                 start=1, min=1, max=MAX_PASSES, variability="fixed"),
        Variable("history_size", "Int32", "parameter",
                 "Samples of displacement history kept for the regenerative chip (must span regeneration_passes "
                 "tooth periods)",
                 start=16384, min=16, max=1048576, variability="fixed"),
        Variable("spindle_speed", "Float64", "input", "Spindle speed (clockwise seen from the spindle, M3)",
                 unit="rad/s", display_unit="rpm", start=0.0, min=0.0, max=1e4),
        Variable("feed_velocity_x", "Float64", "input", "Feed velocity of the tool relative to the workpiece in x",
                 unit="m/s", display_unit="mm/min", start=0.0, min=-10.0, max=10.0),
        Variable("feed_velocity_y", "Float64", "input", "Feed velocity of the tool relative to the workpiece in y",
                 unit="m/s", display_unit="mm/min", start=0.0, min=-10.0, max=10.0),
        Variable("axial_depth", "Float64", "input", "Axial depth of cut a_p", unit="m", display_unit="mm",
                 start=0.003, min=0.0, max=0.1),
        Variable("entry_angle", "Float64", "input", "Angle where a flute enters the cut, relative to the feed",
                 unit="rad", display_unit="deg", start=0.0, min=-TWO_PI, max=TWO_PI),
        Variable("exit_angle", "Float64", "input", "Angle where a flute leaves the cut, relative to the feed",
                 unit="rad", display_unit="deg", start=math.pi, min=-TWO_PI, max=TWO_PI),
        Variable("displacement_x", "Float64", "input", "Tool tip displacement in x (vibration)",
                 unit="m", display_unit="um", start=0.0, min=-0.01, max=0.01),
        Variable("displacement_y", "Float64", "input", "Tool tip displacement in y (vibration)",
                 unit="m", display_unit="um", start=0.0, min=-0.01, max=0.01),
        Variable("Fx", "Float64", "output", "Cutting force on the tool in x", unit="N"),
        Variable("Fy", "Float64", "output", "Cutting force on the tool in y", unit="N"),
        Variable("Fz", "Float64", "output", "Cutting force on the tool in z (along the axis, towards the spindle)",
                 unit="N"),
        Variable("torque", "Float64", "output", "Cutting torque on the spindle", unit="N.m"),
        Variable("power", "Float64", "output", "Cutting power, torque times spindle speed", unit="W",
                 display_unit="kW"),
        Variable("spindle_angle", "Float64", "output", "Angle of flute 0 at the tool tip, clockwise from +y",
                 unit="rad", display_unit="deg"),
        Variable("feed_per_tooth", "Float64", "output", "Feed per tooth f_t = |v_feed|*2*pi/(N*omega)",
                 unit="m", display_unit="mm"),
    ),
)


# ---- closed forms (Altintas, Manufacturing Automation, 2nd ed., eqs. 2.85-2.87 form) ----


def mean_forces(Ktc: float, Krc: float, Kac: float, Kte: float, Kre: float, Kae: float, n_flutes: int,
                axial_depth: float, feed_per_tooth: float, entry_angle: float = 0.0,
                exit_angle: float = math.pi, chip_law: int = CHIP_LAW_LINEAR, mc_t: float = 0.0,
                mc_r: float = 0.0, mc_a: float = 0.0) -> dict[str, float]:
    """Forces on the tool averaged over a revolution, feed along +x, no runout or vibration, for a
    window inside ``0 .. pi`` (where ``f_t*sin(phi) >= 0``): the integral of the element forces over
    the immersion, times N/(2*pi). Independent of the helix (a full revolution sweeps every slice
    over the whole window). SI units; also ``torque_per_radius`` (mean torque / tool radius).
    Closed form for the linear law; the power laws (2, 3) are integrated numerically (adaptive quadrature)."""
    if not 0.0 <= entry_angle <= exit_angle <= math.pi:
        raise ValueError(f"window {entry_angle}..{exit_angle} rad is not inside 0..pi")
    N, a, c = n_flutes, axial_depth, feed_per_tooth
    if chip_law != CHIP_LAW_LINEAR:
        from scipy.integrate import quad  # only the power laws need it

        law = {"chip_law": chip_law, "Ktc": Ktc, "Krc": Krc, "Kac": Kac, "Kte": Kte, "Kre": Kre, "Kae": Kae,
               "mc_t": mc_t, "mc_r": mc_r, "mc_a": mc_a}

        def element(phi: float, direction: str) -> float:
            return float(element_force(law, max(c * math.sin(phi), CHIP_MIN), direction))

        integrands = {"Fx": lambda p: -element(p, "t") * math.cos(p) - element(p, "r") * math.sin(p),
                      "Fy": lambda p: element(p, "t") * math.sin(p) - element(p, "r") * math.cos(p),
                      "Fz": lambda p: element(p, "a"), "torque_per_radius": lambda p: element(p, "t")}
        return {name: N * a / (2 * math.pi) * quad(f, entry_angle, exit_angle, epsabs=0.0, epsrel=1e-11,
                                                     limit=200)[0] for name, f in integrands.items()}

    def at(phi: float) -> np.ndarray:
        fx = (c / 4 * (Ktc * math.cos(2 * phi) - Krc * (2 * phi - math.sin(2 * phi)))
              + (-Kte * math.sin(phi) + Kre * math.cos(phi)))
        fy = (c / 4 * (Ktc * (2 * phi - math.sin(2 * phi)) + Krc * math.cos(2 * phi))
              - (Kte * math.cos(phi) + Kre * math.sin(phi)))
        fz = -Kac * c * math.cos(phi) + Kae * phi
        ft = -Ktc * c * math.cos(phi) + Kte * phi
        return np.array([fx, fy, fz, ft])

    fx, fy, fz, ft = N * a / (2 * math.pi) * (at(exit_angle) - at(entry_angle))
    return {"Fx": fx, "Fy": fy, "Fz": fz, "torque_per_radius": ft}


def mean_slot_forces(Ktc: float, Krc: float, Kac: float, Kte: float, Kre: float, Kae: float, n_flutes: int,
                     axial_depth: float, feed_per_tooth: float, chip_law: int = CHIP_LAW_LINEAR, mc_t: float = 0.0,
                     mc_r: float = 0.0, mc_a: float = 0.0) -> dict[str, float]:
    """Mean forces on the tool in slotting (window 0 .. pi, feed along +x), closed form for every chip-thickness
    law (SI units; floats or casadi expressions, so that calibration can fit through it). Linear law (Altintas'
    identification formulae, linear in the feed per tooth c)::

        Fx = -N*a*Krc*c/4 - N*a*Kre/pi
        Fy = +N*a*Ktc*c/4 + N*a*Kte/pi
        Fz = +N*a*Kac*c/pi + N*a*Kae/2

    Laws 2 and 3 (exponents p = 1 - m_c): the cos-weighted terms integrate to zero over the slot and
    ``integral(sin(phi)**q, 0, pi) = sqrt(pi)*Gamma((q + 1)/2)/Gamma(q/2 + 1)`` (:func:`sine_power_integral`), so::

        Fx = -N*a/(2*pi)*(Krc*h0*(c/h0)**p_r*S(p_r + 1) + 2*Kre)
        Fy = +N*a/(2*pi)*(Ktc*h0*(c/h0)**p_t*S(p_t + 1) + 2*Kte)
        Fz = +N*a/(2*pi)*(Kac*h0*(c/h0)**p_a*S(p_a) + pi*Kae)

    (edge terms 0 under law 2), which is the linear law at m_c = 0 (S(2) = pi/2, S(1) = 2).
    """
    N, a, c = n_flutes, axial_depth, feed_per_tooth
    if chip_law == CHIP_LAW_LINEAR:
        return {"Fx": -N * a * Krc * c / 4 - N * a * Kre / math.pi,
                "Fy": N * a * Ktc * c / 4 + N * a * Kte / math.pi,
                "Fz": N * a * Kac * c / math.pi + N * a * Kae / 2,
                "torque_per_radius": N * a * Ktc * c / math.pi + N * a * Kte / 2}
    if chip_law not in (CHIP_LAW_EXPONENTIAL, CHIP_LAW_POWER_EDGE):
        raise ValueError(f"chip_law {chip_law}: not one of {sorted(CHIP_LAWS.values())}")
    edge = 0.0 if chip_law == CHIP_LAW_EXPONENTIAL else 1.0
    h0, S, k = CHIP_REFERENCE, sine_power_integral, N * a / (2 * math.pi)
    pt, pr, pa = 1 - mc_t, 1 - mc_r, 1 - mc_a
    cut_t = Ktc * h0 * (c / h0) ** pt
    return {"Fx": -k * (Krc * h0 * (c / h0) ** pr * S(pr + 1) + 2 * edge * Kre),
            "Fy": k * (cut_t * S(pt + 1) + 2 * edge * Kte),
            "Fz": k * (Kac * h0 * (c / h0) ** pa * S(pa) + math.pi * edge * Kae),
            "torque_per_radius": k * (cut_t * S(pt) + math.pi * edge * Kte)}


# Lanczos' approximation of log Gamma (g = 7, 9 terms; relative error below 1e-13 for x > 0.5): only arithmetic,
# log and exp, so it works on floats and on casadi expressions alike (casadi has no Gamma function).
_LANCZOS = (0.99999999999980993, 676.5203681218851, -1259.1392167224028, 771.32342877765313, -176.61502916214059,
            12.507343278686905, -0.13857109526572012, 9.9843695780195716e-6, 1.5056327351493116e-7)


def log_gamma(x):  # type: ignore[no-untyped-def]
    """log(Gamma(x)) for x > 0.5 (floats or casadi expressions), Lanczos' approximation."""
    z = x - 1
    series = _LANCZOS[0] + sum(c / (z + i) for i, c in enumerate(_LANCZOS[1:], start=1))
    t = z + 7.5
    log = ca.log if isinstance(x, (ca.SX, ca.MX)) else math.log
    return 0.5 * math.log(2 * math.pi) + (z + 0.5) * log(t) - t + log(series)


def sine_power_integral(q):  # type: ignore[no-untyped-def]
    """integral(sin(phi)**q, phi = 0 .. pi) = sqrt(pi)*Gamma((q + 1)/2)/Gamma(q/2 + 1), q > 0 (floats or casadi)."""
    exp = ca.exp if isinstance(q, (ca.SX, ca.MX)) else math.exp
    return math.sqrt(math.pi) * exp(log_gamma((q + 1) / 2) - log_gamma(q / 2 + 1))


# ---- reference implementation of the FMU's native part (fmus/force/model.c) ----


class HistoryTooShort(RuntimeError):
    """The displacement history does not reach one tooth period back (the FMU's doStep fails)."""


class DisplacementHistory:
    """The displacement history of the force FMUs (fmus/common/displacement_history.c, CuttingForce and
    ForceNet): a ring of ``size`` samples ``(t, x, y)`` taken at each doStep from the inputs at its start; the
    delayed displacement by linear interpolation over those samples and the current inputs, one period ``T``
    before the current inputs (before the oldest sample: its value, "no regeneration yet"). The current inputs are
    the newest sample when they equal it (after a doStep: the inputs held over it), else a sample at ``time``
    (inputs set since), so the current and the delayed displacement are one period apart, as in the delay
    equation. Same operations in the same order as the C."""

    def __init__(self, size: int):
        self.samples: deque[tuple[float, float, float]] = deque(maxlen=int(size))

    def delayed(self, time: float, period: float, x: float, y: float) -> tuple[float, float]:
        newest = self.samples[-1] if self.samples else None
        now = newest[0] if newest is not None and newest[1] == x and newest[2] == y else time
        samples = list(self.samples) + [(now, x, y)]
        td = now - period
        if td <= samples[0][0]:
            return samples[0][1], samples[0][2]
        i = bisect.bisect_right([s[0] for s in samples], td) - 1
        (t0, x0, y0), (t1, x1, y1) = samples[i], samples[i + 1]
        w = (td - t0) / (t1 - t0)
        return x0 + w * (x1 - x0), y0 + w * (y1 - y0)

    def record(self, time: float, step_size: float, x: float, y: float, period: float, cutting: bool,
               periods: int = 1) -> None:
        """Stores the sample; raises HistoryTooShort when the full ring does not reach ``periods`` periods back."""
        self.samples.append((time, x, y))
        if len(self.samples) == self.samples.maxlen and cutting and self.samples[0][0] > time - periods * period:
            raise HistoryTooShort(f"history of {len(self.samples)} samples does not reach {periods} tooth "
                                  "period(s) back")


def tooth_period(values: Mapping[str, float]) -> float:
    """T = 2*pi/(N*omega) of the history (the spindle speed at least OMEGA_MIN)."""
    return TWO_PI / (float(int(values["n_flutes"])) * max(values["spindle_speed"], OMEGA_MIN))


class ForceReference:
    """The FMU step by step, in Python: the displacement history (:class:`DisplacementHistory`), the
    generated equations with the delayed displacement, and the spindle-angle update. Same operations in the
    same order as model.c."""

    def __init__(self, values: Mapping[str, float], start_time: float = 0.0):
        self.model = CUTTING_FORCE
        names = {v.name for v in self.model.of("parameter") + self.model.of("input")}
        self.values = {k: x for k, x in {**self.model.defaults(), **values}.items() if k in names}
        self.start_time = self.time = start_time  # time: the importer's; the model advances by the step clock
        self.clock = StepClock()
        self.history = DisplacementHistory(int(self.values["history_size"]))
        self.angle = 0.0

    def set(self, values: Mapping[str, float]) -> None:
        self.values.update(values)

    def tooth_period(self) -> float:
        return tooth_period(self.values)

    def passes(self) -> int:
        return int(self.values["regeneration_passes"])

    def delayed(self, periods: int = 1) -> tuple[float, float]:
        return self.history.delayed(self.start_time + self.clock.seconds(), periods * self.tooth_period(),
                                    self.values["displacement_x"], self.values["displacement_y"])

    def delayed_states(self) -> dict[str, float]:
        """The native states as model.c fills them: k = 1 .. regeneration_passes periods ago, the others as k = 1."""
        states = {}
        for name, axis, k in DELAYED:
            if axis == "x":
                dx, dy = self.delayed(k) if k <= self.passes() else (states["delayed_displacement_x"],
                                                                    states["delayed_displacement_y"])
            states[name] = dx if axis == "x" else dy
        return states

    def outputs(self) -> np.ndarray:
        result = self.model.evaluate(**self.values, angle=self.angle, **self.delayed_states())
        return np.array([float(result[v.name]) for v in self.model.of("output")])

    def step(self, h: float) -> np.ndarray:
        v = self.values
        start = self.start_time + self.clock.seconds()
        taken = self.clock.advance(self.time, h)
        self.history.record(start, taken, v["displacement_x"], v["displacement_y"], self.tooth_period(),
                            v["spindle_speed"] >= OMEGA_MIN and v["axial_depth"] > 0, self.passes())
        new = self.model.step(taken, **v, angle=self.angle, **dict.fromkeys(DELAYED_STATES, 0.0))
        self.angle = float(new["angle"])
        self.time = self.time + h
        return self.outputs()


def reference_trajectory(points: Sequence[Mapping[str, float]], step_size: float) -> np.ndarray:
    """Outputs after each step when initialized with points[0], then each point set and stepped
    (the protocol of tests/fmu_helpers.py): points x outputs."""
    reference = ForceReference(points[0])
    rows = []
    for point in points:
        reference.set(point)
        rows.append(reference.step(step_size))
    return np.array(rows)


def initial_native_states(values: Mapping[str, float | np.ndarray]) -> dict[str, float | np.ndarray]:
    """The native states before any step: no history yet, so the delayed displacement is the
    current one (no regeneration)."""
    defaults = CUTTING_FORCE.defaults()
    return {name: values.get(f"displacement_{axis}", defaults[f"displacement_{axis}"]) for name, axis, _ in DELAYED}


def initial_outputs(values: Mapping[str, float | np.ndarray]) -> np.ndarray:
    """Outputs before any step (initialization), points x outputs: the spindle angle at its start
    value and the delayed displacement equal to the current one."""
    result = CUTTING_FORCE.evaluate(**{"angle": 0.0, **initial_native_states(values), **values})
    return np.stack([np.atleast_1d(result[v.name]) for v in CUTTING_FORCE.of("output")], axis=-1)


def identify_slot_coefficients(feeds_per_tooth: Sequence[float], Fx: Sequence[float], Fy: Sequence[float],
                               Fz: Sequence[float], n_flutes: int, axial_depth: float) -> dict[str, float]:
    """The six coefficients from mean slotting forces on the tool at several feeds per tooth (SI):
    Altintas' identification, a least-squares line per axis inverted through :func:`mean_slot_forces`."""
    c = np.asarray(feeds_per_tooth, dtype=float)
    if c.size < 2 or np.ptp(c) == 0:
        raise ValueError("identification needs at least two different feeds per tooth")
    (sx, ix), (sy, iy), (sz, iz) = (np.polyfit(c, np.asarray(f, dtype=float), 1) for f in (Fx, Fy, Fz))
    na = n_flutes * axial_depth
    return {"Ktc": 4 * sy / na, "Krc": -4 * sx / na, "Kac": math.pi * sz / na,
            "Kte": math.pi * iy / na, "Kre": -math.pi * ix / na, "Kae": 2 * iz / na}
