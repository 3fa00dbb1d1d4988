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

Parallel calibration (:mod:`milling_twin.orchestrator.calibrate.parallel`): with an :attr:`FmuOutputs.executor`,
a Jacobian's column simulations are submitted at once (:func:`evaluate`, a picklable :class:`Simulation` run in a
temporary folder of the worker) and accounted in the serial loop's order, so the cache and the counts end as the
serial loop leaves them; ``remote`` sends every simulation there; a start solved elsewhere logs what it asked
(:attr:`FmuOutputs.log`) and :meth:`FmuOutputs.replay` accounts for it here.
"""
from __future__ import annotations

import os
import tempfile
import time
from collections import OrderedDict
from collections.abc import Sequence
from concurrent.futures import Executor, Future
from dataclasses import dataclass, field, replace
from pathlib import Path

import casadi as ca
import numpy as np

from milling_twin.orchestrator.calibrate.pairing import Pairs, at_rows
from milling_twin.orchestrator.calibrate.parameters import Parameter
from milling_twin.orchestrator.calibrate.residuals import ResidualModel, from_outputs
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.results import load_results
from milling_twin.orchestrator.scenario import Ref, Scenario, with_values

__all__ = ["Access", "Evaluation", "FD_METHODS", "FmuOutputs", "JacobianAccess", "Simulation", "default_step",
           "evaluate", "evaluate_all", "fmu_residuals"]

FD_METHODS = ("forward", "central")
EPS = float(np.finfo(float).eps)


def default_step(method: str) -> float:
    """Relative step balancing truncation and rounding errors: sqrt(eps) forward, eps^(1/3) central."""
    return EPS ** 0.5 if method == "forward" else EPS ** (1.0 / 3.0)


@dataclass(frozen=True)
class Failure:
    theta: tuple[float, ...]
    message: str


@dataclass(frozen=True)
class Simulation:
    """One evaluation's recipe, picklable (it is what a worker process receives): the scenario (FMU paths
    absolute), the fitted parameters' names and bounds, the recorded outputs and the pairs' row times."""

    scenario: Scenario
    refs: tuple[Ref | str, ...]  # with_values keys, parameters order
    outputs: tuple[str, ...]
    row_time: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    scale: np.ndarray

    def __call__(self, theta: np.ndarray, work_dir: Path) -> np.ndarray:
        """The outputs at the row times (pairs x outputs) of a run into ``work_dir``; raises when it fails."""
        # IPOPT keeps strictly inside the bounds (strict_bounds); what lies outside by rounding is clipped
        theta = np.where(np.abs(theta - np.clip(theta, self.lower, self.upper)) <= 1e-9 * self.scale,
                         np.clip(theta, self.lower, self.upper), theta)
        case = with_values(self.scenario, dict(zip(self.refs, (float(v) for v in theta))))
        result = run(case, work_dir, progress=False)
        if result.signal is not None:  # SIGINT/SIGTERM/SIGHUP stop the calibration, not only this simulation
            raise KeyboardInterrupt(f"{result.signal} during a simulation of the fit")
        if result.status != "completed":
            raise RuntimeError(f"the simulation ended {result.status}")
        return at_rows(load_results(result.run_dir), list(self.outputs), self.row_time)


@dataclass(frozen=True)
class Evaluation:
    """What a worker sends back for one simulation: the outputs, or the failure's cause."""

    y: np.ndarray | None
    error: str | None  # "ExceptionType: message"
    seconds: float


def evaluate(simulation: Simulation, theta: np.ndarray) -> Evaluation:
    """A task of the parallel finite-difference Jacobian (module level: it pickles). The run goes to a
    temporary folder of the worker (several run at once; the worker may be another machine)."""
    t0 = time.perf_counter()
    try:
        with tempfile.TemporaryDirectory(prefix="milling_twin_evaluation_") as folder:
            y = simulation(theta, Path(folder))
        return Evaluation(y, None, time.perf_counter() - t0)
    except Exception as exc:  # noqa: BLE001 - any failure of the FMUs or the run is a failed evaluation
        return Evaluation(None, f"{type(exc).__name__}: {exc}", time.perf_counter() - t0)


def evaluate_all(simulation: Simulation, thetas: Sequence[np.ndarray]) -> list[Evaluation]:
    """A task of several evaluations, one after the other (a Jacobian's columns in as many tasks as workers:
    fewer round trips)."""
    return [evaluate(simulation, theta) for theta in thetas]


@dataclass(frozen=True)
class Access:
    """One evaluation asked of :class:`FmuOutputs` (for :meth:`FmuOutputs.replay`): its outputs, and, if it
    was simulated rather than found in the cache, the failure's cause (None: it ran) and its time."""

    key: bytes
    theta: np.ndarray
    y: np.ndarray
    simulated: bool
    error: str | None = None
    seconds: float = 0.0


@dataclass(frozen=True)
class JacobianAccess:
    """One Jacobian asked of :class:`FmuOutputs`: its value and the evaluations it made (None: it was cached)."""

    key: bytes
    theta: np.ndarray
    nominal: np.ndarray | None
    jacobian: np.ndarray
    accesses: list[Access | JacobianAccess] | None = field(default=None)


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
        self.simulation = Simulation(_absolute_fmus(self.scenario), tuple(self.refs), tuple(self.outputs),
                                     self.row_time, self.lower, self.upper, self.scale)
        self._cache: OrderedDict[bytes, np.ndarray] = OrderedDict()
        self._jacobians: OrderedDict[bytes, np.ndarray] = OrderedDict()
        self.cache_size = cache_size
        self.failures: list[Failure] = []
        self.simulations = 0
        self.simulation_time = 0.0
        # parallel calibration (orchestrator/calibrate/parallel.py): where the Jacobian's columns are simulated
        # (None: here, one after the other), and the log of the evaluations asked (None: not kept)
        self.executor: Executor | None = None
        self.remote = False  # every simulation a task of the executor (not only the Jacobian's columns)
        self.tasks: int | None = None  # a Jacobian's column simulations in this many tasks (None: one each)
        self.log: list[Access | JacobianAccess] | None = None

    def detached(self) -> "FmuOutputs":
        """A copy for another process: the same evaluations, no cache, no failures, no executor, no log."""
        copy = object.__new__(FmuOutputs)
        copy.__dict__.update(self.__dict__)
        copy._cache, copy._jacobians, copy.failures = OrderedDict(), OrderedDict(), []
        copy.simulations, copy.simulation_time, copy.executor, copy.remote, copy.log = 0, 0.0, None, False, None
        copy.tasks = None
        return copy

    def __getstate__(self) -> dict:
        if self.executor is not None:
            raise TypeError("an FmuOutputs with an executor does not pickle: send FmuOutputs.detached()")
        return self.__dict__.copy()

    @property
    def shape(self) -> tuple[int, int]:
        return self.row_time.size, len(self.outputs)

    def describe(self) -> str:
        return (f"FMU re-simulation with {self.method} finite differences (relative step {self.step:.3g}, "
                f"{len(self.names) * (1 if self.method == 'forward' else 2)} runs per Jacobian), "
                "projected Levenberg-Marquardt")

    def _simulate(self, theta: np.ndarray) -> np.ndarray:
        return self.simulation(theta, self.work_dir)

    def __call__(self, theta: np.ndarray) -> np.ndarray:
        """Outputs at the pairs (pairs x outputs); NaN where the simulation failed (cause in failures)."""
        theta = np.asarray(theta, dtype=float).ravel()
        key = theta.tobytes()
        if key in self._cache:
            self._cache.move_to_end(key)
            y = self._cache[key]
            if self.log is not None:
                self.log.append(Access(key, theta, y, simulated=False))
            return y
        if self.remote and self.executor is not None:
            e = self._wait(self.executor.submit(evaluate, self.simulation, theta))
            return self._store(key, theta, e.y, e.error, e.seconds)
        t0 = time.perf_counter()
        try:
            y, error = self._simulate(theta), None
        except Exception as exc:  # noqa: BLE001 - any failure of the FMUs or the run is a failed evaluation
            y, error = None, f"{type(exc).__name__}: {exc}"
        return self._store(key, theta, y, error, time.perf_counter() - t0)

    @staticmethod
    def _wait(future: Future) -> Evaluation:
        try:
            return future.result()
        except Exception as exc:  # noqa: BLE001 - the worker itself failed (e.g. died with its FMU)
            return Evaluation(None, f"the worker failed: {type(exc).__name__}: {exc}", 0.0)

    def _store(self, key: bytes, theta: np.ndarray, y: np.ndarray | None, error: str | None,
               seconds: float) -> np.ndarray:
        """Count and cache one simulation (``y`` None: it failed with ``error``)."""
        if y is None:
            values = ", ".join(f"{n} = {v:.6g}" for n, v in zip(self.names, theta))
            self.failures.append(Failure(tuple(theta), f"{error} (at {values})"))
            y = np.full(self.shape, np.nan)
        self.simulations += 1
        self.simulation_time += seconds
        self._cache[key] = y
        if len(self._cache) > self.cache_size:
            self._cache.popitem(last=False)
        if self.log is not None:
            self.log.append(Access(key, theta, y, True, error, seconds))
        return y

    def vector(self, theta: np.ndarray) -> np.ndarray:
        """Outputs pair-major (all outputs of pair 0, then pair 1, ...)."""
        return self(theta).ravel()

    def jacobian(self, theta: np.ndarray, nominal: np.ndarray | None = None) -> np.ndarray:
        """d vector / d theta (SI), (pairs * outputs) x parameters. With an :attr:`executor`, the columns'
        simulations run there at once; the Jacobian, the cache and the counts are those of the serial loop."""
        theta = np.asarray(theta, dtype=float).ravel()
        key = theta.tobytes()
        if key in self._jacobians:
            if self.log is not None:
                self.log.append(JacobianAccess(key, theta, nominal, self._jacobians[key]))
            return self._jacobians[key]
        outer, self.log = self.log, ([] if self.log is not None else None)
        try:
            y0 = self.vector(theta) if nominal is None else np.asarray(nominal, dtype=float).ravel()
            columns = self._columns(theta)
            if self.executor is not None:
                self._run_ahead([moved for column in columns for moved in column])
            jac = np.empty((y0.size, theta.size))
            for j, column in enumerate(columns):
                if len(column) == 2:  # central
                    plus, minus = column
                    jac[:, j] = (self.vector(plus) - self.vector(minus)) / (plus[j] - minus[j])
                else:
                    moved, = column
                    jac[:, j] = (self.vector(moved) - y0) / (moved[j] - theta[j])  # the step as represented
        finally:
            accesses, self.log = self.log, outer
        self._store_jacobian(key, jac)
        if outer is not None:
            outer.append(JacobianAccess(key, theta, nominal, jac, accesses))
        return jac

    def _columns(self, theta: np.ndarray) -> list[tuple[np.ndarray, ...]]:
        """Per parameter, the moved parameter vectors its column is computed from (in that order)."""
        columns = []
        for j in range(theta.size):
            h = self.step * max(abs(theta[j]), self.scale[j])
            up, down = theta[j] + h <= self.upper[j], theta[j] - h >= self.lower[j]
            if self.method == "central" and up and down:
                plus, minus = theta.copy(), theta.copy()
                plus[j] += h
                minus[j] -= h
                columns.append((plus, minus))
            else:
                moved = theta.copy()
                moved[j] += h if up else -h
                columns.append((moved,))
        return columns

    def _store_jacobian(self, key: bytes, jac: np.ndarray) -> None:
        self._jacobians[key] = jac
        if len(self._jacobians) > 4:
            self._jacobians.popitem(last=False)

    def _run_ahead(self, thetas: list[np.ndarray]) -> None:
        """Simulate on the executor, all at once, the evaluations of ``thetas`` (in this order) that the
        serial loop would simulate (the cache's least-recently-used order played on the keys), then account
        for them in that order: the cache and the counts end as the serial loop leaves them."""
        order = OrderedDict((k, None) for k in self._cache)
        missing: dict[bytes, np.ndarray] = {}
        for theta in thetas:
            key = theta.tobytes()
            if key in order:
                order.move_to_end(key)
                continue
            order[key] = None
            if len(order) > self.cache_size:
                order.popitem(last=False)
            missing.setdefault(key, theta)
        keys = list(missing)
        groups = np.array_split(np.arange(len(keys)), min(self.tasks or len(keys), len(keys))) if keys else []
        futures = [(group, self.executor.submit(evaluate_all, self.simulation, [missing[keys[i]] for i in group]))
                   for group in groups]
        done: dict[bytes, Evaluation] = {}  # by key: the order of completion does not matter
        for group, future in futures:
            try:
                done.update(zip((keys[i] for i in group), future.result()))
            except Exception as exc:  # noqa: BLE001 - the worker itself failed (e.g. died with its FMU)
                done.update((keys[i], Evaluation(None, f"the worker failed: {type(exc).__name__}: {exc}", 0.0))
                            for i in group)
        for theta in thetas:
            key = theta.tobytes()
            if key in self._cache:
                self._cache.move_to_end(key)
                if self.log is not None:
                    self.log.append(Access(key, theta, self._cache[key], simulated=False))
            else:
                e = done[key]
                self._store(key, theta, e.y, e.error, e.seconds)

    def replay(self, log: Sequence[Access | JacobianAccess]) -> None:
        """Account here for the evaluations another process made (a start run on a worker), in their order,
        as if they had been asked here: an evaluation this cache holds is not counted (the serial loop would
        have found it), one it does not hold is cached and counted (with its failure, if any). The evaluations
        are deterministic (checked at the initial values), so the values are those this process would get."""
        for a in log:
            if isinstance(a, JacobianAccess):
                if a.key in self._jacobians:
                    continue
                if a.accesses is None:  # the worker had it cached, this process has not: compute it as serial
                    self.jacobian(a.theta, a.nominal)
                    continue
                self.replay(a.accesses)
                self._store_jacobian(a.key, a.jacobian)
            elif a.key in self._cache:
                self._cache.move_to_end(a.key)
            else:
                error = a.error if a.simulated else ("the simulation failed (first reported at these values)"
                                                     if not np.all(np.isfinite(a.y)) else None)
                self._store(a.key, a.theta, None if error is not None else a.y, error, a.seconds)

    def clear_cache(self) -> None:
        """Forget the cached evaluations (timing a repeated fit from the same start)."""
        self._cache.clear()
        self._jacobians.clear()


def _absolute_fmus(scenario: Scenario) -> Scenario:
    """``scenario`` with its FMUs by absolute path (a worker process may run in another folder)."""
    return replace(scenario, instances=tuple(replace(i, path=Path(os.path.abspath(i.path)))
                                             for i in scenario.instances))


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
                   derivatives=fmu.describe(), keep_alive=callback, origin=(fmu, pairs))
