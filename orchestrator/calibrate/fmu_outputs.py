"""Fitted outputs evaluated by the FMUs themselves, with a finite-difference Jacobian: the path for
models whose outputs the models/ expressions cannot give (outputs or states computed by the FMU's C
code: Workpiece, CuttingForce with its displacement history, ForceNet; instances upstream with states;
dynamic models not recorded every step), and on request for any model.

:class:`FmuOutputs` maps the fitted parameters (SI) to the fitted outputs at the pairs' row times by
re-simulating the scenario through the orchestrator (``milling_twin.orchestrator.master.run``, the compiled fast
path where available) with the trial values applied by name, recording only the fitted outputs and
stopping at the last row the pairs need. The outputs are read at the pairs exactly as the pairs of
the initial run were (linear between rows), so at the initial values the evaluation reproduces the
initial run's outputs bit for bit (checked, as the exact path checks its equations).

Jacobian by finite differences, column j from re-simulations with parameter j moved by
``h_j = step * max(|theta_j|, scale_j)``:

* ``"forward"`` (default step sqrt(eps) = 1.5e-8): ``(y(theta + h e_j) - y(theta)) / h``, p runs;
  truncation error ``h/2 |y''|`` plus rounding ``eps |y| / h``: about 1e-8 relative for smooth outputs;
* ``"central"`` (default step eps^(1/3) = 6.1e-6): ``(y(theta + h e_j) - y(theta - h e_j)) / 2h``,
  2p runs, about 1e-11 relative (truncation ``h^2/6 |y'''|`` plus ``eps |y| / h``).

A step that would leave the parameter's bounds (the FMU refuses values outside its range) is taken
the other way (forward), or one-sided (central). Outputs linear in a parameter (the cutting-force
coefficients) have no truncation error. Where the output is not differentiable in the parameter
(a chip thickness crossing zero as the runout changes) the difference quotient is whatever the step
sees: fit such parameters with care (the slot_forces kind searches the spindle phases instead).

The evaluations are cached by parameter values (IPOPT asks for the outputs, the gradient and the
Gauss-Newton Hessian at the same point), and wrapped as casadi Callbacks (:func:`fmu_residuals`) so
that the solver module (:mod:`milling_twin.orchestrator.calibrate.lsq`: its projected Levenberg-Marquardt method,
one Jacobian per iteration), multi-start and statistics of the exact path serve this one. A failed simulation gives non-finite outputs and its cause is kept
(:attr:`FmuOutputs.failures`): the solver reports it for the start (and IPOPT backs off from a
failing trial point).
"""
from __future__ import annotations

import time
from collections import OrderedDict
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import casadi as ca
import numpy as np

from milling_twin.orchestrator.calibrate.pairing import Pairs, at_rows
from milling_twin.orchestrator.calibrate.parameters import Parameter
from milling_twin.orchestrator.calibrate.residuals import ResidualModel, from_outputs
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.results import load_results
from milling_twin.orchestrator.scenario import Ref, Scenario, with_values

__all__ = ["FD_METHODS", "FmuOutputs", "default_step", "fmu_residuals"]

FD_METHODS = ("forward", "central")
EPS = float(np.finfo(float).eps)


def default_step(method: str) -> float:
    """Relative step balancing truncation and rounding errors: sqrt(eps) forward, eps^(1/3) central."""
    return EPS ** 0.5 if method == "forward" else EPS ** (1.0 / 3.0)


@dataclass(frozen=True)
class Failure:
    theta: tuple[float, ...]
    message: str


class FmuOutputs:
    """theta (SI, ``parameters`` order) -> fitted ``outputs`` at ``row_time`` (pairs x outputs)."""

    def __init__(self, scenario: Scenario, parameters: Sequence[Parameter], outputs: Sequence[Ref],
                 row_time: np.ndarray, work_dir: Path, *, method: str = "forward", step: float | None = None,
                 cache_size: int = 64) -> None:
        if method not in FD_METHODS:
            raise ValueError(f"finite-difference method {method!r}: one of {', '.join(FD_METHODS)}")
        self.parameters = tuple(parameters)
        self.names = [q.name for q in parameters]
        self.refs = [q.ref or q.name for q in parameters]  # with_values keys
        self.outputs = [str(o) for o in outputs]  # their columns in the results
        self.row_time = np.asarray(row_time, dtype=float)
        self.method = method
        self.step = default_step(method) if step is None else float(step)
        self.work_dir = Path(work_dir)
        last = float(self.row_time.max()) if self.row_time.size else scenario.start_time + scenario.output_interval
        # the row at or after the last pair, on the output grid (rows are at start + k * output_interval)
        rows = np.ceil((last - scenario.start_time) / scenario.output_interval - 1e-9)
        stop = min(scenario.stop_time, scenario.start_time + max(rows, 1.0) * scenario.output_interval)
        self.scenario = replace(scenario, outputs=tuple(outputs),
                                stop_time=stop, name=f"{scenario.name.removesuffix('_initial')}_evaluation")
        self.lower = np.array([q.lower for q in parameters])
        self.upper = np.array([q.upper for q in parameters])
        self.scale = np.array([q.scale for q in parameters])
        self._cache: OrderedDict[bytes, np.ndarray] = OrderedDict()
        self._jacobians: OrderedDict[bytes, np.ndarray] = OrderedDict()
        self.cache_size = cache_size
        self.failures: list[Failure] = []
        self.simulations = 0
        self.simulation_time = 0.0

    @property
    def shape(self) -> tuple[int, int]:
        return self.row_time.size, len(self.outputs)

    def describe(self) -> str:
        return (f"FMU re-simulation with {self.method} finite differences (relative step {self.step:.3g}, "
                f"{len(self.names) * (1 if self.method == 'forward' else 2)} runs per Jacobian), "
                "projected Levenberg-Marquardt")

    def _simulate(self, theta: np.ndarray) -> np.ndarray:
        # IPOPT keeps strictly inside the bounds (strict_bounds); what lies outside by rounding is clipped
        theta = np.where(np.abs(theta - np.clip(theta, self.lower, self.upper)) <= 1e-9 * self.scale,
                         np.clip(theta, self.lower, self.upper), theta)
        case = with_values(self.scenario, dict(zip(self.refs, (float(v) for v in theta))))
        result = run(case, self.work_dir, progress=False)
        if result.status != "completed":
            raise RuntimeError(f"the simulation ended {result.status}")
        return at_rows(load_results(result.run_dir), self.outputs, self.row_time)

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        """Outputs at the pairs (pairs x outputs); NaN where the simulation failed (cause in failures)."""
        theta = np.asarray(theta, dtype=float).ravel()
        key = theta.tobytes()
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        t0 = time.perf_counter()
        try:
            y = self._simulate(theta)
        except Exception as exc:  # noqa: BLE001 - any failure of the FMUs or the run is a failed evaluation
            values = ", ".join(f"{n} = {v:.6g}" for n, v in zip(self.names, theta))
            self.failures.append(Failure(tuple(theta), f"{type(exc).__name__}: {exc} (at {values})"))
            y = np.full(self.shape, np.nan)
        self.simulations += 1
        self.simulation_time += time.perf_counter() - t0
        self._cache[key] = y
        if len(self._cache) > self.cache_size:
            self._cache.popitem(last=False)
        return y

    def vector(self, theta: np.ndarray) -> np.ndarray:
        """Outputs pair-major (all outputs of pair 0, then pair 1, ...)."""
        return self(theta).ravel()

    def jacobian(self, theta: np.ndarray, nominal: np.ndarray | None = None) -> np.ndarray:
        """d vector / d theta (SI), (pairs * outputs) x parameters."""
        theta = np.asarray(theta, dtype=float).ravel()
        key = theta.tobytes()
        if key in self._jacobians:
            return self._jacobians[key]
        y0 = self.vector(theta) if nominal is None else np.asarray(nominal, dtype=float).ravel()
        jac = np.empty((y0.size, theta.size))
        for j in range(theta.size):
            h = self.step * max(abs(theta[j]), self.scale[j])
            up, down = theta[j] + h <= self.upper[j], theta[j] - h >= self.lower[j]
            if self.method == "central" and up and down:
                plus, minus = theta.copy(), theta.copy()
                plus[j] += h
                minus[j] -= h
                jac[:, j] = (self.vector(plus) - self.vector(minus)) / (plus[j] - minus[j])
            else:
                moved = theta.copy()
                moved[j] += h if up else -h
                jac[:, j] = (self.vector(moved) - y0) / (moved[j] - theta[j])  # the step as represented
        self._jacobians[key] = jac
        if len(self._jacobians) > 4:
            self._jacobians.popitem(last=False)
        return jac

    def clear_cache(self) -> None:
        """Forget the cached evaluations (timing a repeated fit from the same start)."""
        self._cache.clear()
        self._jacobians.clear()


class _Jacobian(ca.Callback):
    def __init__(self, name: str, fmu: FmuOutputs, opts: dict) -> None:
        ca.Callback.__init__(self)
        self.fmu = fmu
        self.construct(name, opts)

    def get_n_in(self) -> int:
        return 2

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(len(self.fmu.names), 1) if i == 0 else ca.Sparsity.dense(int(np.prod(self.fmu.shape)), 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(int(np.prod(self.fmu.shape)), len(self.fmu.names))

    def eval(self, arg):
        nominal = np.asarray(arg[1], dtype=float).ravel()
        return [ca.DM(self.fmu.jacobian(np.asarray(arg[0], dtype=float).ravel(), nominal))]


class _Outputs(ca.Callback):
    """casadi view of :class:`FmuOutputs`: theta -> outputs (pair-major), Jacobian by finite differences."""

    def __init__(self, name: str, fmu: FmuOutputs) -> None:
        ca.Callback.__init__(self)
        self.fmu = fmu
        self._jacobian: _Jacobian | None = None
        self.construct(name, {})

    def get_n_in(self) -> int:
        return 1

    def get_n_out(self) -> int:
        return 1

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(len(self.fmu.names), 1)

    def get_sparsity_out(self, i: int) -> ca.Sparsity:
        return ca.Sparsity.dense(int(np.prod(self.fmu.shape)), 1)

    def eval(self, arg):
        return [ca.DM(self.fmu.vector(np.asarray(arg[0], dtype=float).ravel()))]

    def has_jacobian(self) -> bool:
        return True

    def get_jacobian(self, name: str, inames, onames, opts) -> ca.Function:
        self._jacobian = _Jacobian(name, self.fmu, opts)  # casadi does not own Python callbacks: keep it alive
        return self._jacobian


def fmu_residuals(fmu: FmuOutputs, pairs: Pairs) -> ResidualModel:
    """The residual model of :mod:`milling_twin.orchestrator.calibrate.residuals` on ``pairs`` with the outputs from ``fmu``."""
    n, n_out = fmu.shape
    if len(pairs) != n:
        raise ValueError(f"{len(pairs)} pairs, the evaluator was made for {n}")
    callback = _Outputs("fmu_outputs", fmu)

    def residual(i: int) -> str:
        k, o = divmod(i, n_out)
        return f"{fmu.outputs[o]} at recorded t = {pairs.recorded_time[k]:.6g} s (simulated t = {pairs.row_time[k]:.6g} s)"

    model = from_outputs(lambda th: ca.reshape(callback(th), n_out, n), fmu.parameters, n_out, n,
                         describe_residual=residual, describe_variable=lambda j: fmu.names[j])
    return replace(model, problem=replace(model.problem, failures=lambda: [f.message for f in fmu.failures],
                                          strict_bounds=True, algorithm="levenberg-marquardt"),
                   derivatives=fmu.describe(), keep_alive=callback)
