"""The slot-milling force model that calibration fits: the CuttingForce equations (any chip-thickness law) at a
recording's conditions, seen through the MeasuringChain (the dynamometer and fixture dynamics), as the
per-revolution waveform in the recordings' axes.

Both pieces come from models/: the force from ``milling_twin.models.cutting_force.equations`` (a casadi
Function of the fitted parameters and the spindle angle), the chain from
``milling_twin.models.measuring_chain.frequency_response``'s per-mode terms. The waveform of a recording is
periodic (one revolution; the spindle runs at its nominal speed), so the chain acts on it harmonic by harmonic:
the force is evaluated on ``OVERSAMPLE`` points per recorded sample over one revolution, transformed (a constant
real DFT matrix), every harmonic k multiplied by the chain's response at k times the spindle frequency, and
transformed back at the recorded samples' angles. That is the chain's periodic steady state, which the
MeasuringChain FMU reaches after its transient (the FMU holds the force over a step: its response is this one
delayed by half a step, see models/measuring_chain.py).

The force's evaluations over the angles (and their derivatives, most of a fit's time) run in ``threads`` threads
of casadi's map (:func:`map_threads`: the CPUs this process may use, at most ``MAX_MAP_THREADS``): every thread
computes its own angles, so the numbers are those of one thread to the bit. The recordings share one force
function (what differs between them, :attr:`SlotModel.varying`, is its third input), compiled to machine code with
its derivatives when ``compile_options`` hold casadi's just-in-time options (``compiled.py``): the same numbers.

``layout`` (:class:`SlotModel`) names the fitted parameters in order: the coefficients of the law (force
instance), the runout offset (optional), the chain's modes (chain instance), then one spindle phase per recording
(nuisance, last).
"""
from __future__ import annotations

import functools
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from milling_twin.models.cutting_force import (CHIP_LAW_EXPONENTIAL, CHIP_LAW_LINEAR, CHIP_LAW_POWER_EDGE,
                                               CUTTING_FORCE, equations)
from milling_twin.models.measuring_chain import AXES as CHAIN_AXES
from milling_twin.models.measuring_chain import (MEASURING_CHAIN, damping_name, frequency_name,
                                                 frequency_response, frequency_response_parts, gain_name,
                                                 parameter_vector, response_function)
from milling_twin.orchestrator.validation.slot_milling import AXES  # recorded column -> model output

__all__ = ["CHAIN_INSTANCE", "LAW_COEFFICIENTS", "OVERSAMPLE", "SlotModel", "chain_parameter_names",
           "map_threads"]

FORCE_INSTANCE = "force"
CHAIN_INSTANCE = "chain"
OVERSAMPLE = 2  # force points per recorded sample: what the DFT of the force aliases is 0.2 % of its range
LAW_COEFFICIENTS = {
    CHIP_LAW_LINEAR: ("Ktc", "Krc", "Kac", "Kte", "Kre", "Kae"),
    CHIP_LAW_EXPONENTIAL: ("Ktc", "Krc", "Kac", "mc_t", "mc_r", "mc_a"),
    CHIP_LAW_POWER_EDGE: ("Ktc", "Krc", "Kac", "Kte", "Kre", "Kae", "mc_t", "mc_r", "mc_a"),
}
MAX_MAP_THREADS = 4  # the force maps 100 to 1,000 angles per call: more threads cost more to start than they save
RECORDED_AXES = tuple(AXES)  # the files' Fx, Fy, Fz
MODEL_AXES = tuple(AXES[a] for a in RECORDED_AXES)  # the model's outputs compared with them


def map_threads() -> int:
    """Threads for the force's map over the angles: the CPUs this process may run on (its affinity, where the
    platform tells it), at most :data:`MAX_MAP_THREADS`."""
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, min(MAX_MAP_THREADS, usable))


def chain_parameter_names(modes: int) -> list[str]:
    """The MeasuringChain parameters of its first ``modes`` modes: frequency, damping, then the gain matrix."""
    names: list[str] = []
    for i in range(modes):
        names += [frequency_name(i), damping_name(i)] + [gain_name(i, o, j) for o in CHAIN_AXES for j in CHAIN_AXES]
    return names


def _dft(points: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(cos, sin) rows of the real DFT over ``points`` samples (harmonics 0 .. points/2) and the weights of the
    inverse (1 for the mean and the Nyquist line, 2 otherwise), divided by ``points``."""
    k = np.arange(points // 2 + 1)[:, None]
    angle = 2 * math.pi * k * np.arange(points)[None, :] / points
    weight = np.full(k.size, 2.0)
    weight[0] = 1.0
    if points % 2 == 0:
        weight[-1] = 1.0
    return np.cos(angle), np.sin(angle), weight / points


@dataclass
class SlotModel:
    """The fitted quantities and the model waveform of each recording (module text).

    ``constants``: the force instance's parameters and inputs per recording (SI, its ``chip_law`` among them);
    ``coefficients``: the force parameters fitted (the law's coefficients, the runout); ``chain_modes``: modes of
    the chain (0: no chain); ``spindle_hz``: the spindle frequency of each recording; ``points``: its samples per
    revolution."""

    constants: list[dict[str, float]]
    coefficients: list[str]
    chain_modes: int
    spindle_hz: list[float]
    points: list[int]
    threads: int = field(default_factory=map_threads)
    compile_options: dict = field(default_factory=dict)  # casadi's options of the force function (compiled.py)

    def __post_init__(self) -> None:
        self.chain = chain_parameter_names(self.chain_modes)
        self.n_model = len(self.coefficients) + len(self.chain)
        # what differs between the recordings (speed, feed, depth) is an input of the one force function, the rest
        # is folded in: one function (one compilation) serves every recording
        self.varying = [a.name for a in CUTTING_FORCE.arguments
                        if a.name not in self.coefficients and a.name != "angle"
                        and len({float(c[a.name]) for c in self.constants}) > 1]
        self._function = self._force_function()

    @property
    def law(self) -> int:
        return int(self.constants[0]["chip_law"])

    # ---- the force ----
    def _force_function(self) -> ca.Function:
        """(force parameters, angle, conditions) -> forces in the recordings' axes: the conditions are the
        :attr:`varying` constants, the others folded in."""
        theta = ca.SX.sym("theta", len(self.coefficients))
        angle = ca.SX.sym("angle")
        conditions = ca.SX.sym("conditions", len(self.varying))
        values = {}
        for arg in CUTTING_FORCE.arguments:
            if arg.name in self.coefficients:
                values[arg.name] = theta[self.coefficients.index(arg.name)]
            elif arg.name == "angle":
                values[arg.name] = angle
            elif arg.name in self.varying:
                values[arg.name] = conditions[self.varying.index(arg.name)]
            else:
                values[arg.name] = ca.SX(float(self.constants[0][arg.name]))
        out = equations(values)
        return ca.Function("forces", [theta, angle, conditions], [ca.vertcat(*[out[a] for a in MODEL_AXES])],
                           self.compile_options)

    def conditions(self, i: int) -> np.ndarray:
        """The :attr:`varying` constants of recording ``i`` (the force function's third input)."""
        return np.array([float(self.constants[i][name]) for name in self.varying])

    def _mapped(self, angles: int) -> ca.Function:
        """The force over ``angles`` angles at once, in :attr:`threads` threads."""
        return (self._function.map(angles, "thread", self.threads) if self.threads > 1
                else self._function.map(angles))

    def forces(self, i: int, theta_model: np.ndarray, angles: np.ndarray) -> np.ndarray:
        """The force of recording ``i`` at ``angles`` (radians; len(angles) x 3, numpy)."""
        n = len(self.coefficients)
        return np.asarray(self._mapped(angles.size)(np.repeat(np.asarray(theta_model)[:n, None], angles.size, axis=1),
                                                    angles[None, :],
                                                    np.repeat(self.conditions(i)[:, None], angles.size, axis=1)),
                          dtype=float).T

    # ---- the chain ----
    def chain_values(self, theta):  # type: ignore[no-untyped-def]
        """The MeasuringChain's parameters in the model part of ``theta`` (floats or casadi), with n_modes."""
        start = len(self.coefficients)
        return {"n_modes": self.chain_modes, **{name: theta[start + j] for j, name in enumerate(self.chain)}}

    def harmonics_hz(self, i: int) -> np.ndarray:
        """The frequencies the recording's samples resolve: the spindle frequency times 0 .. points/2."""
        return np.arange(self.points[i] // 2 + 1) * self.spindle_hz[i]

    def waveform(self, theta: ca.MX, i: int, phase: ca.MX) -> ca.MX:
        """The model's per-revolution waveform of recording ``i`` at its recorded samples (points x 3), MX."""
        points = self.points[i]
        grid = points * (OVERSAMPLE if self.chain_modes else 1)
        base = ca.DM(2 * math.pi * np.arange(grid) / grid).T
        force = self._mapped(grid)(ca.repmat(theta[:len(self.coefficients)], 1, grid), phase + base,
                                   ca.repmat(ca.DM(self.conditions(i)), 1, grid)).T
        if not self.chain_modes:
            return force
        # the harmonics the samples resolve (the recorder's anti-aliasing filter removes the others)
        harmonics = points // 2 + 1
        cos, sin, _ = _dft(grid)
        real = ca.DM(cos[:harmonics]) @ force  # harmonics x 3
        imag = -ca.DM(sin[:harmonics]) @ force
        omega = ca.DM(2 * math.pi * self.harmonics_hz(i)).T
        chain = ca.repmat(parameter_vector(self.chain_values(theta)), 1, harmonics)
        measured_re, measured_im = _chain_product().map(harmonics)(chain, omega, real.T, imag.T)  # 3 x harmonics
        back_cos, back_sin, _ = _dft(points)
        # the harmonics of the force (on the finer grid) at the sample angles: 2 Re(c_k e^(i k angle)), c_0 once
        weight = np.full(harmonics, 2.0 / grid)
        weight[0] = 1.0 / grid
        inverse_cos = ca.DM((back_cos * weight[:, None]).T)
        inverse_sin = ca.DM((back_sin * weight[:, None]).T)
        return inverse_cos @ measured_re.T - inverse_sin @ measured_im.T

    def fine_waveform(self, theta_model: np.ndarray, i: int, fine: int) -> np.ndarray:
        """The waveform over ``fine`` equal angles from 0 (fine x 3, numpy): for the phase search. With a chain,
        the harmonics the recording resolves only, as :meth:`waveform` has them."""
        force = self.forces(i, theta_model, 2 * math.pi * np.arange(fine) / fine)
        if not self.chain_modes:
            return force
        harmonics = self.points[i] // 2 + 1
        spectrum = np.fft.rfft(force, axis=0)
        response = frequency_response({k: float(v) for k, v in self.chain_values(theta_model).items()},
                                      self.harmonics_hz(i))
        measured = np.zeros_like(spectrum)
        measured[:harmonics] = np.einsum("kij,kj->ki", response, spectrum[:harmonics])
        return np.fft.irfft(measured, n=fine, axis=0)


@functools.lru_cache(maxsize=1)
def _chain_product() -> ca.Function:
    """(chain parameter vector, angular frequency, Re X, Im X) -> (Re, Im) of H(j omega) X for one harmonic X of
    the force (3 axes): mapped over a recording's harmonics it is one node of the fit's graph, whose derivatives
    casadi forms for all harmonics at once."""
    parameters = ca.SX.sym("parameters", response_function().size1_in(0))
    omega, x_re, x_im = ca.SX.sym("omega"), ca.SX.sym("x_re", 3), ca.SX.sym("x_im", 3)
    h_re, h_im = (ca.reshape(h, 3, 3) for h in response_function()(parameters, omega))
    return ca.Function("chain_product", [parameters, omega, x_re, x_im],
                       [h_re @ x_re - h_im @ x_im, h_re @ x_im + h_im @ x_re])


def chain_bounds(name: str) -> tuple[float, float]:
    """The MeasuringChain's own range of a parameter (SI)."""
    v = MEASURING_CHAIN.variable(name)
    return (-math.inf if v.min is None else float(v.min)), (math.inf if v.max is None else float(v.max))




@functools.lru_cache(maxsize=16)
def _mode_function(hz: tuple[float, ...]) -> ca.Function:
    """(frequency, damping) -> (Re, Im) of G - 1 at ``hz`` for one mode: the chain's own frequency response (a
    single mode with the identity as its gain matrix), compiled once per set of frequencies."""
    frequency, damping = ca.SX.sym("frequency"), ca.SX.sym("damping")
    values = {"n_modes": 1, "frequency_1": frequency, "damping_1": damping,
              **{gain_name(0, o, j): float(o == j) for o in CHAIN_AXES for j in CHAIN_AXES}}
    real, imag = frequency_response_parts(values, np.array(hz))
    return ca.Function("mode", [frequency, damping], [ca.vertcat(*[r[0, 0] - 1 for r in real]),
                                                       ca.vertcat(*[m[0, 0] for m in imag])])


def mode_minus_one(frequency: float, damping: float, hz: np.ndarray) -> np.ndarray:
    """G(j 2 pi hz) - 1 of one chain mode (complex, per frequency)."""
    real, imag = _mode_function(tuple(float(f) for f in np.asarray(hz).ravel()))(frequency, damping)
    return np.asarray(real).ravel() + 1j * np.asarray(imag).ravel()


@dataclass
class ChainHarmonics:
    """What the chain's identification needs of each recording: the model force's harmonics X (at the fitted
    phase; 1 .. below the samples' Nyquist line, complex, harmonics x 3), the recorded waveform's W, their
    frequencies and the weight of each harmonic in the time-domain sum of squares (Parseval: 2 times the number
    of revolutions and of points)."""

    force: list[np.ndarray]
    recorded: list[np.ndarray]
    hz: list[np.ndarray]
    weight: list[np.ndarray]

    def gains(self, modes: Sequence[tuple[float, float]], axis_weights: np.ndarray
              ) -> tuple[np.ndarray, float]:
        """For given (frequency, damping) of each mode: the gain matrices (modes x 3 x 3) that minimise the sum of
        squares, a linear least-squares problem per measured axis, and that sum (weighted per axis)."""
        columns = []  # per recording: harmonics x (modes * 3) complex regressors
        for x, hz in zip(self.force, self.hz):
            columns.append(np.concatenate([mode_minus_one(f, z, hz)[:, None] * x for f, z in modes], axis=1))
        a = np.concatenate(columns) * np.sqrt(np.concatenate(self.weight))[:, None]
        gains = np.zeros((len(modes), 3, 3))
        ssr = 0.0
        for o in range(3):
            b = np.concatenate([w[:, o] - x[:, o] for w, x in zip(self.recorded, self.force)])
            b = b * np.sqrt(np.concatenate(self.weight))
            stacked, rhs = np.concatenate([a.real, a.imag]), np.concatenate([b.real, b.imag])
            solution, *_ = np.linalg.lstsq(stacked, rhs, rcond=None)
            gains[:, o, :] = solution.reshape(len(modes), 3)
            ssr += axis_weights[o] ** 2 * float(np.sum((stacked @ solution - rhs) ** 2))
        return gains, ssr


def chain_harmonics(model: SlotModel, theta_model: np.ndarray, phases: Sequence[float],
                    waves: Sequence[np.ndarray], revolutions: Sequence[int]) -> ChainHarmonics:
    """The harmonics of the model force (without the chain) and of the recorded waveforms (module text)."""
    force, recorded, hz, weight = [], [], [], []
    for i, (phase, wave, revs) in enumerate(zip(phases, waves, revolutions)):
        points = len(wave)
        grid = points * OVERSAMPLE
        angles = phase + 2 * math.pi * np.arange(grid) / grid
        f = model.forces(i, theta_model, angles)
        harmonics = np.arange(1, (points + 1) // 2)  # the Nyquist line (half of it unseen) is left out
        force.append(np.fft.rfft(f, axis=0)[harmonics] / grid)
        recorded.append(np.fft.rfft(wave, axis=0)[harmonics] / points)
        hz.append(harmonics * model.spindle_hz[i])
        weight.append(np.full(harmonics.size, 2.0 * revs * points))
    return ChainHarmonics(force, recorded, hz, weight)


def identify_chain(harmonics: ChainHarmonics, modes: int, axis_weights: np.ndarray,
                   frequency_range: tuple[float, float], damping_range: tuple[float, float]) -> dict[str, float]:
    """The chain's modes from the recordings' harmonics with the force fixed (variable projection: the gains are
    linear given the modes' frequencies and dampings, solved exactly; the frequencies by a grid search, one mode
    after the other, then all together by Nelder-Mead on their logarithms). The chain's parameters by name."""
    from scipy.optimize import minimize

    lo, hi = frequency_range
    grid_f = np.geomspace(lo, hi, 60)
    grid_z = np.geomspace(max(damping_range[0], 0.01), min(damping_range[1], 0.3), 6)
    chosen: list[tuple[float, float]] = []
    for _ in range(modes):
        best = min(((harmonics.gains(chosen + [(f, z)], axis_weights)[1], f, z) for f in grid_f for z in grid_z))
        chosen.append((best[1], best[2]))
    bounds_f, bounds_z = np.log(frequency_range), np.log(damping_range)

    def objective(x: np.ndarray) -> float:
        x = np.clip(x.reshape(-1, 2), [bounds_f[0], bounds_z[0]], [bounds_f[1], bounds_z[1]])
        return harmonics.gains([tuple(np.exp(row)) for row in x], axis_weights)[1]

    start = np.log(np.array(chosen)).ravel()
    result = minimize(objective, start, method="Nelder-Mead", options={"maxiter": 400 * modes, "xatol": 1e-4,
                                                                       "fatol": 1e-10})
    x = np.clip(result.x.reshape(-1, 2), [bounds_f[0], bounds_z[0]], [bounds_f[1], bounds_z[1]])
    found = [tuple(np.exp(row)) for row in x]
    gains, _ = harmonics.gains(found, axis_weights)
    values: dict[str, float] = {}
    for i, (f, z) in enumerate(found):
        values[frequency_name(i)] = float(f)
        values[damping_name(i)] = float(z)
        values.update({gain_name(i, o, j): float(gains[i, a, b]) for a, o in enumerate(CHAIN_AXES)
                       for b, j in enumerate(CHAIN_AXES)})
    return values
