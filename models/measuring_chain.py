"""The measuring chain: the force on a dynamometer as the dynamometer records it, through the modes of the
dynamometer and its fixture, discretized exactly.

Per mode i (up to ``MAX_MODES``, ``n_modes`` of them active) and input axis j in x, y, z a damped oscillator
driven by the force on that axis, and the recorded force the applied one plus what the modes add through a
3x3 gain matrix R_i per mode (cross-coupling: a force in x moves the y channel):

    q_ij'' + 2 zeta_i w_i q_ij' + w_i^2 q_ij = w_i^2 F_j,        w_i = 2 pi frequency_i,
    measured = F + sum_i R_i (q_i - F).

The transfer matrix from F to measured is therefore

    H(s) = I + sum_i R_i (G_i(s) - 1),        G_i(s) = w_i^2 / (s^2 + 2 zeta_i w_i s + w_i^2):

its static gain is exactly the identity (a mean force passes unchanged, whatever the gains), the modes add
the resonances, and its value at high frequency is the direct feedthrough I - sum_i R_i. ``frequency_response``
evaluates H(j 2 pi f) from the same per-mode terms the equations use (``_mode``, ``_gain``), numerically or as
casadi expressions (``frequency_response_parts``), so what calibration fits is what the FMU runs.

Over a step of size h the force is held constant (a co-simulation step) and ``update`` is the exact solution of
each oscillator for that force (a zero-order hold: any step size is stable, a piecewise-constant force gives
the exact response). The sampled FMU's frequency response is ``sampled_frequency_response`` (exact, from the
same update). Split H = (H - D) + D with D = I - sum_i R_i the direct feedthrough (``feedthrough``): a force
sequence F_k, each held over [t_k, t_k + h], reaches the modes as its fundamental times the hold's
e^{-j w h/2} sinc(w h/2) (``zero_order_hold``), while the feedthrough reads the force currently set (no delay
when the next force is set before the outputs are read, the orchestrator's order; a whole step h when they are
read first). So the sampled response is (H(j w) - D) e^{-j w h/2} sinc(w h/2) + D (or D e^{-j w h}) up to the
aliases of the modes: at most 1.4e-6 of |H| over the harmonics of 100 Hz to 2 kHz with h = 10 us and the
three modes (900, 1700, 3100 Hz) of tests/test_measuring_chain.py, 1e4 times less at h = 1 us. To first order in w h it is
H(j w) e^{-j w h/2} when the gains sum to the identity (no feedthrough); otherwise the feedthrough's
half-step offset, |D| w h/2, is the first-order difference.
"""
from __future__ import annotations

import functools
import math
from typing import Any, Mapping, Sequence

import casadi as ca
import numpy as np

from milling_twin.models.definition import ModelDefinition, State, Variable

MAX_MODES = 4
AXES = ("x", "y", "z")

# Default modes: frequency [Hz], damping ratio [1]. With the gains at their default 0 (and n_modes 0) the chain
# passes the force through unchanged.
DEFAULT_MODES = ((800.0, 0.05), (1600.0, 0.05), (2400.0, 0.05), (3200.0, 0.05))
FREQUENCY_RANGE = (1.0, 5e4)  # Hz
DAMPING_RANGE = (1e-4, 0.95)  # underdamped: the exact update uses the damped natural frequency
GAIN_RANGE = (-100.0, 100.0)
FORCE_RANGE = (-1e6, 1e6)  # N


def frequency_name(i: int) -> str:
    """The natural frequency of mode ``i`` (0-based): frequency_1 .. frequency_4."""
    return f"frequency_{i + 1}"


def damping_name(i: int) -> str:
    return f"damping_{i + 1}"


def gain_name(i: int, out: str, into: str) -> str:
    """The gain of mode ``i`` (0-based) from the force on axis ``into`` to the measured force on axis ``out``:
    gain_<i+1>_<out><into>, e.g. gain_1_yx (mode 1, force in x seen in y)."""
    return f"gain_{i + 1}_{out}{into}"


def state_names(i: int, axis: str) -> tuple[str, str]:
    """(displacement, velocity) of mode ``i``'s oscillator driven by the force on ``axis``: q_<axis><i+1>, v_..."""
    return f"q_{axis}{i + 1}", f"v_{axis}{i + 1}"


def _mode(v: Mapping[str, Any], i: int) -> tuple[Any, Any, Any]:
    """(active, natural angular frequency [rad/s], damping ratio) of mode ``i``: the one definition of a mode the
    equations, the update and the frequency response share."""
    return v["n_modes"] > i, 2 * math.pi * v[frequency_name(i)], v[damping_name(i)]


def _gain(v: Mapping[str, Any], i: int, out: str, into: str) -> Any:
    return v[gain_name(i, out, into)]


def equations(v: Mapping[str, ca.SX]) -> dict[str, ca.SX]:
    """measured = F + sum over active modes of R_i (q_i - F)."""
    out: dict[str, ca.SX] = {}
    for o in AXES:
        measured = v[f"force_{o}"]
        for i in range(MAX_MODES):
            active, _, _ = _mode(v, i)
            added = sum(_gain(v, i, o, j) * (v[state_names(i, j)[0]] - v[f"force_{j}"]) for j in AXES)
            measured = measured + ca.if_else(active, added, 0)
        out[f"measured_{o}"] = measured
    return out


def update(v: Mapping[str, ca.SX], h: ca.SX) -> dict[str, ca.SX]:
    """Exact damped-oscillator solution over h for the force held at its current value; inactive modes stay 0."""
    new: dict[str, ca.SX] = {}
    for i in range(MAX_MODES):
        active, wn, zeta = _mode(v, i)
        root = ca.sqrt(1 - zeta ** 2)
        wd = wn * root
        decay = ca.exp(-zeta * wn * h)
        c, s = ca.cos(wd * h), ca.sin(wd * h)
        for j in AXES:
            q_name, v_name = state_names(i, j)
            static = v[f"force_{j}"]
            e0, v0 = v[q_name] - static, v[v_name]
            e1 = decay * (e0 * c + (v0 + zeta * wn * e0) / wd * s)
            v1 = decay * (v0 * c - (wn * e0 + zeta * v0) / root * s)
            new[q_name] = ca.if_else(active, static + e1, 0)
            new[v_name] = ca.if_else(active, v1, 0)
    return new


def _variables() -> tuple[Variable, ...]:
    variables: list[Variable] = [
        Variable("n_modes", "Int32", "parameter",
                 "Number of active modes of the measuring chain (0: the force passes unchanged; a mode switched on "
                 "starts at rest)", start=0, min=0, max=MAX_MODES)]
    for i, (f, zeta) in enumerate(DEFAULT_MODES):
        n = i + 1
        variables += [
            Variable(frequency_name(i), "Float64", "parameter", f"Natural frequency of mode {n} of the measuring chain",
                     unit="Hz", start=f, min=FREQUENCY_RANGE[0], max=FREQUENCY_RANGE[1]),
            Variable(damping_name(i), "Float64", "parameter", f"Damping ratio of mode {n} of the measuring chain",
                     start=zeta, min=DAMPING_RANGE[0], max=DAMPING_RANGE[1]),
        ]
        variables += [
            Variable(gain_name(i, o, j), "Float64", "parameter",
                     f"Gain of mode {n} from the force in {j} to the measured force in {o}",
                     start=0.0, min=GAIN_RANGE[0], max=GAIN_RANGE[1])
            for o in AXES for j in AXES]
    variables += [Variable(f"force_{a}", "Float64", "input", f"Force loading the dynamometer in its {a} axis",
                           unit="N", start=0.0, min=FORCE_RANGE[0], max=FORCE_RANGE[1]) for a in AXES]
    variables += [Variable(f"measured_{a}", "Float64", "output", f"Force the dynamometer records in its {a} axis",
                           unit="N") for a in AXES]
    return tuple(variables)


def _states() -> tuple[State, ...]:
    return tuple(
        State(state_names(i, j)[k], f"{'Response' if k == 0 else 'Rate of the response'} of mode {i + 1} to the "
              f"force in {j}", unit="N" if k == 0 else "N/s")
        for i in range(MAX_MODES) for j in AXES for k in (0, 1))


MEASURING_CHAIN = ModelDefinition(
    identifier="MeasuringChain",
    description="Dynamometer and fixture dynamics: up to 4 modes with cross-coupling gains between the x, y, z "
                "channels, static gain 1, exact discretization; the measured force from the applied one",
    default_step_size=1e-5,
    default_stop_time=0.1,
    equations=equations,
    update=update,
    states=_states(),
    variables=_variables(),
)


# ---- frequency response ----


def _parameter_starts() -> dict[str, float]:
    return {v.name: float(v.start) for v in MEASURING_CHAIN.of("parameter")}


def _checked(values: Mapping[str, Any]) -> Mapping[str, Any]:
    unknown = sorted(set(values) - set(_parameter_starts()))
    if unknown:
        raise ValueError(f"MeasuringChain has no parameter {', '.join(repr(n) for n in unknown)} (parameters: n_modes, "
                         "frequency_<i>, damping_<i>, gain_<i>_<out><in>)")
    return values


def _values(values: Mapping[str, Any]) -> dict[str, Any]:
    """The parameters with their defaults for what ``values`` leaves out; numbers as casadi DM."""
    merged = {**_parameter_starts(), **_checked(values)}
    return {name: ca.DM(float(x)) if isinstance(x, (int, float, np.number)) else x for name, x in merged.items()}


def _response_at(v: Mapping[str, Any], omega: Any) -> tuple[Any, Any]:
    """H(j omega) as (real, imaginary) 3x3 casadi matrices: I + sum over the active modes of R_i (G_i - 1)."""
    re = [[1.0 if o == j else 0.0 for j in AXES] for o in AXES]
    im = [[0.0] * len(AXES) for _ in AXES]
    for i in range(MAX_MODES):
        active, wn, zeta = _mode(v, i)
        a, b = wn ** 2 - omega ** 2, 2 * zeta * wn * omega
        den = a ** 2 + b ** 2
        g_re, g_im = wn ** 2 * a / den - 1, -wn ** 2 * b / den  # G_i(j omega) - 1
        for r, o in enumerate(AXES):
            for c, j in enumerate(AXES):
                gain = ca.if_else(active, _gain(v, i, o, j), 0)
                re[r][c] = re[r][c] + gain * g_re
                im[r][c] = im[r][c] + gain * g_im
    return ca.vertcat(*[ca.horzcat(*row) for row in re]), ca.vertcat(*[ca.horzcat(*row) for row in im])


def frequency_response_parts(values: Mapping[str, Any], frequencies_hz: Sequence[float] | np.ndarray
                             ) -> tuple[list[Any], list[Any]]:
    """H(j 2 pi f) for each frequency f as (real parts, imaginary parts): two lists with one 3x3 casadi matrix
    (rows: measured x, y, z; columns: force x, y, z) per frequency. ``values``: parameters by name, numbers or
    casadi expressions (SX or MX), the others at their defaults; the same ``_mode`` and ``_gain`` terms as the
    equations."""
    v = _values(values)
    real: list[Any] = []
    imag: list[Any] = []
    for f in np.asarray(frequencies_hz, dtype=float).ravel():
        re, im = _response_at(v, 2 * math.pi * float(f))
        real.append(re)
        imag.append(im)
    return real, imag


@functools.lru_cache(maxsize=1)
def response_function() -> ca.Function:
    """(the parameter vector of :func:`parameter_vector`, angular frequency) -> (Re H, Im H), each the vec() of the
    3x3 matrix (column-major): the expression of ``_response_at`` compiled once. For numbers it replaces term by
    term evaluation in DM (one call for 51 frequencies: 135 ms against 0.8 ms); for casadi expressions, mapped
    over the frequencies, it keeps a fit's graph to one node where the per-frequency matrices of
    ``frequency_response_parts`` make thousands."""
    names = list(_parameter_starts())
    parameters, omega = ca.SX.sym("parameters", len(names)), ca.SX.sym("omega")
    re, im = _response_at({n: parameters[k] for k, n in enumerate(names)}, omega)
    return ca.Function("frequency_response", [parameters, omega], [ca.vec(re), ca.vec(im)])


def parameter_vector(values: Mapping[str, Any]) -> Any:
    """The chain's parameters in the order :func:`response_function` takes them, the defaults for what ``values``
    leaves out: a numpy vector for numbers, else a casadi column of the expressions' type (SX or MX)."""
    merged = {**_parameter_starts(), **_checked(values)}
    entries = [merged[n] for n in _parameter_starts()]
    if all(isinstance(x, (int, float, np.number)) or (isinstance(x, ca.DM) and x.numel() == 1) for x in entries):
        return np.array([float(x) for x in entries])
    return ca.vertcat(*entries)


def frequency_response(values: Mapping[str, Any], frequencies_hz: Sequence[float] | np.ndarray) -> Any:
    """H(j 2 pi f): a complex array (n frequencies, 3 measured axes, 3 force axes) for numeric ``values``; with
    casadi expressions among them, the (real, imag) lists of ``frequency_response_parts``."""
    parameters = parameter_vector(values)
    if not isinstance(parameters, np.ndarray):
        return frequency_response_parts(values, frequencies_hz)
    omega = 2 * math.pi * np.asarray(frequencies_hz, dtype=float).ravel()
    if omega.size == 0:
        return np.zeros((0, 3, 3), dtype=complex)
    re, im = response_function().map(omega.size)(np.repeat(parameters[:, None], omega.size, axis=1), omega[None, :])
    # columns are vec() of each 3x3 (column-major): transpose back to rows = measured axes
    response = (np.asarray(re) + 1j * np.asarray(im)).T.reshape(-1, 3, 3)
    return np.transpose(response, (0, 2, 1))


def feedthrough(values: Mapping[str, Any]) -> Any:
    """D = I - sum of the active modes' gains: H at infinite frequency, the part of the measured force that
    follows the applied one without delay. A 3x3 numpy array for numeric ``values``, else a casadi matrix."""
    v = _values(values)
    rows = [[(1.0 if o == j else 0.0) - sum(ca.if_else(_mode(v, i)[0], _gain(v, i, o, j), 0)
                                            for i in range(MAX_MODES)) for j in AXES] for o in AXES]
    matrix = ca.vertcat(*[ca.horzcat(*row) for row in rows])
    return np.asarray(matrix) if isinstance(matrix, ca.DM) else matrix


def zero_order_hold(frequencies_hz: Sequence[float] | np.ndarray, step_size: float) -> np.ndarray:
    """e^{-j w h/2} sinc(w h/2), w = 2 pi f: what holding a sampled sinusoid over each step does to it (the
    fundamental of the staircase relative to the samples)."""
    x = np.pi * np.asarray(frequencies_hz, dtype=float) * step_size  # w h / 2
    return np.exp(-1j * x) * np.sinc(x / np.pi)


def _transition(values: Mapping[str, float], step_size: float) -> np.ndarray:
    """Per mode, the 2x2 matrix taking (q - F, q') over one step, from ``update`` itself (unit states, F = 0)."""
    phi = np.zeros((MAX_MODES, 2, 2))
    for i in range(int(values["n_modes"])):
        q, qd = state_names(i, "x")
        for column, (q0, v0) in enumerate(((1.0, 0.0), (0.0, 1.0))):
            new = MEASURING_CHAIN.step(step_size, **{**values, q: q0, qd: v0})
            phi[i, :, column] = [float(new[q]), float(new[qd])]
    return phi


def sampled_frequency_response(values: Mapping[str, float], frequencies_hz: Sequence[float] | np.ndarray,
                               step_size: float, set_before_read: bool = True) -> np.ndarray:
    """The exact frequency response of the FMU stepped at ``step_size``: a force sequence F_k = F e^{j w k h},
    each held over one step, against the outputs read at the step ends (complex array (n, 3, 3)). With
    ``set_before_read`` the force of the new communication point is set before the outputs are read (the
    orchestrator's Gauss-Seidel order: the feedthrough sees the current force); otherwise the outputs are read
    with the force of the step just made (the feedthrough a step late). From the model's own ``update``."""
    v = {name: float(np.asarray(x)) for name, x in {**_parameter_starts(), **_checked(values)}.items()}
    phi = _transition(v, step_size)
    result = []
    for f in np.asarray(frequencies_hz, dtype=float).ravel():
        z = np.exp(2j * math.pi * f * step_size)
        feed = 1.0 if set_before_read else 1 / z  # the force the feedthrough sees, per unit force at t_k
        response = feed * np.eye(3, dtype=complex)
        for i in range(int(v["n_modes"])):
            p = phi[i]
            # q_{k+1} = F_k + p (q_k - F_k, v_k) with F_k = z^k, q_k = Q z^k, v_k = V z^k
            system = np.array([[z - p[0, 0], -p[0, 1]], [-p[1, 0], z - p[1, 1]]])
            q_response = np.linalg.solve(system, np.array([1 - p[0, 0], -p[1, 0]]))[0]
            gains = np.array([[v[gain_name(i, o, j)] for j in AXES] for o in AXES])
            response = response + gains * (q_response - feed)
        result.append(response)
    return np.array(result).reshape(-1, 3, 3)


# ---- simulation of the chain on a force record ----


def _simulator(n_steps: int) -> ca.Function:
    """(states, forces 3 x n, parameters, h) -> (states after each step, measured 3 x n), the update and the
    equations of MEASURING_CHAIN accumulated over n steps (casadi mapaccum)."""
    key = f"simulate_{n_steps}"
    cache = MEASURING_CHAIN._cache
    if key not in cache:
        if "simulate_step" not in cache:
            states = [s.name for s in MEASURING_CHAIN.states]
            parameters = [p.name for p in MEASURING_CHAIN.of("parameter")]
            x = ca.SX.sym("x", len(states))
            force = ca.SX.sym("force", len(AXES))
            p = ca.SX.sym("p", len(parameters))
            h = ca.SX.sym("h")
            v = {**{n: x[k] for k, n in enumerate(states)}, **{n: p[k] for k, n in enumerate(parameters)},
                 **{f"force_{a}": force[k] for k, a in enumerate(AXES)}}
            new = update(v, h)
            x_next = ca.vertcat(*[new[n] for n in states])
            measured = equations({**v, **{n: x_next[k] for k, n in enumerate(states)}})
            y = ca.vertcat(*[measured[f"measured_{a}"] for a in AXES])
            cache["simulate_step"] = ca.Function("measuring_chain_step", [x, force, p, h], [x_next, y])
        cache[key] = cache["simulate_step"].mapaccum(n_steps)
    return cache[key]


def simulate(values: Mapping[str, float], forces: np.ndarray, step_size: float) -> np.ndarray:
    """The measured forces (n, 3) for the applied ``forces`` (n, 3): from rest, force k held over step k, the
    outputs read at the end of each step with that force still set (what the FMU gives stepped that way)."""
    forces = np.asarray(forces, dtype=float)
    if forces.ndim != 2 or forces.shape[1] != len(AXES):
        raise ValueError(f"MeasuringChain.simulate: forces must be (n, 3), got {forces.shape}")
    merged = {**_parameter_starts(), **_checked(values)}
    p = [float(merged[v.name]) for v in MEASURING_CHAIN.of("parameter")]
    x0 = np.zeros(len(MEASURING_CHAIN.states))
    _, measured = _simulator(len(forces))(x0, forces.T, p, step_size)
    return np.asarray(measured).T
