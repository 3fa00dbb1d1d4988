"""Parallel calibration: the simulations of a fit through the FMUs (the starts of a multi-start fit, the columns
of its finite-difference Jacobians) as tasks of the executor of the studies
(:mod:`milling_twin.orchestrator.study.executor`: N local worker processes or an existing dask cluster), with the
result of the serial fit bit for bit.

``[solver] workers = N`` (0 or absent: the serial fit, in this process) or ``scheduler = "tcp://host:8786"``
(or a scheduler file) of the spec; ``milling-twin calibrate --workers N --scheduler ADDR``.

What runs where. The optimiser (casadi, whose functions built around Python callbacks do not pickle, and the
Levenberg-Marquardt steps) stays in this process; only simulations go out, each a task
(:func:`~milling_twin.orchestrator.calibrate.fmu_outputs.evaluate`: the scenario with FMU paths made absolute, the
parameter values; it runs into a temporary folder of the worker and sends back the outputs at the pairs or the
failure's cause):

* more than one start: the starts run at once, each in a thread of this process with its own residual model,
  solver and cache (:meth:`FmuOutputs.detached`); every simulation they ask for is a task, a Jacobian's columns
  submitted together, so the workers share the simulations of all starts whatever each start's length;
* one start, the second (noise-weighted) stage and the statistics: each finite-difference Jacobian's column
  simulations are submitted together;
* a Jacobian's column simulations go out in as many tasks as there are local workers
  (:func:`~milling_twin.orchestrator.calibrate.fmu_outputs.evaluate_all`: fewer round trips), one task each on a
  scheduler's cluster (its size is not known here).

The same numbers come out because every evaluation is deterministic (the calibration checks that a re-run at the
initial values reproduces the initial run bit for bit) and nothing is combined in completion order: each start's
outcome is its own computation, the outcomes are taken in start order, and each start's log of evaluations is
replayed into this process's cache in that order (:meth:`FmuOutputs.replay`), so the cache, the count of
simulations and the failures are those of the serial loop, and the second stage and the statistics that follow
find what they would have found; a Jacobian is assembled column by column. The seeded starts are drawn here.
Only the wall times differ. The exact path (casadi derivatives of the models/ equations, no simulation in the
fit) starts no workers and keeps its starts in this process (scenario_fit.py).
"""
from __future__ import annotations

from collections.abc import Iterator
from concurrent.futures import Executor, Future, ThreadPoolExecutor
from contextlib import contextmanager
from dataclasses import replace

import numpy as np
from tqdm import tqdm

from milling_twin.orchestrator.calibrate.fmu_outputs import FmuOutputs, fmu_residuals
from milling_twin.orchestrator.calibrate.lsq import LeastSquaresSolver, StartOutcome
from milling_twin.orchestrator.calibrate.pairing import Pairs
from milling_twin.orchestrator.calibrate.residuals import ResidualModel
from milling_twin.orchestrator.calibrate.spec import SolverSpec

__all__ = ["calibration_executor", "columns_on", "solve_starts"]

MAX_THREADS = 32  # starts solved at once (each mostly waits for its simulations)


def _fmu(model: ResidualModel) -> tuple[FmuOutputs, Pairs] | None:
    return model.origin if model.origin is not None and isinstance(model.origin[0], FmuOutputs) else None


def solve_starts(model: ResidualModel, lsq: LeastSquaresSolver, thetas: np.ndarray, p: np.ndarray,
                 executor: Executor, progress: bool = False, tasks: int | None = None) -> list[StartOutcome] | None:
    """Every start of ``thetas`` (rows, SI) at once, their simulations on ``executor`` (a Jacobian's columns in
    ``tasks`` tasks; None: one each); the outcomes in start order. None: this model's evaluations cannot leave
    this process (the exact path), the caller runs them."""
    origin = _fmu(model)
    if origin is None:
        return None
    fmu, pairs = origin
    runs: list[StartOutcome | tuple[FmuOutputs, ResidualModel, LeastSquaresSolver, np.ndarray]] = []
    for i, theta in enumerate(thetas):  # built here, one after the other (casadi's plugin loading is not threaded)
        try:
            x0 = model.start(theta)
        except Exception as exc:  # noqa: BLE001 - the start's simulation failed: report, go on (as serial)
            runs.append(StartOutcome(i, np.asarray(theta) / model.scale(), "failed",
                                     f"the start's initial simulation failed: {type(exc).__name__}: {exc}"))
            continue
        own = fmu.detached()
        own.executor, own.remote, own.tasks, own.log = executor, True, tasks, []
        own_model = fmu_residuals(own, pairs)
        problem = replace(own_model.problem, algorithm=lsq.problem.algorithm)  # the algorithm [solver] chose
        runs.append((own, own_model, LeastSquaresSolver(problem, max_iterations=lsq.max_iterations,
                                                         tolerance=lsq.tolerance, hessian=lsq.hessian), x0))
    outcomes = []
    with ThreadPoolExecutor(max(1, min(MAX_THREADS, len(runs)))) as threads:
        pending: list[StartOutcome | Future] = [
            run if isinstance(run, StartOutcome) else threads.submit(run[2].solve, run[3], p, index=i)
            for i, run in enumerate(runs)]
        for i, item in enumerate(tqdm(pending, desc="calibration starts", unit="start", disable=not progress,
                                      leave=False)):
            if isinstance(item, StartOutcome):
                outcomes.append(item)
                continue
            own, _, _, x0 = runs[i]
            try:
                outcome = item.result()
            except Exception as exc:  # noqa: BLE001 - a start that breaks is reported, the next one runs
                outcome = StartOutcome(i, x0, "failed", f"solver failed: {type(exc).__name__}: {exc}")
            fmu.replay(own.log)
            outcomes.append(outcome)
    return outcomes


@contextmanager
def columns_on(model: ResidualModel, executor: Executor | None, tasks: int | None = None) -> Iterator[None]:
    """Within: the finite-difference Jacobians of ``model`` (FMU path) simulate their columns on ``executor``,
    in ``tasks`` tasks (None: one per simulation)."""
    origin = _fmu(model) if executor is not None else None
    if origin is None:
        yield
        return
    fmu = origin[0]
    before = fmu.executor, fmu.tasks
    fmu.executor, fmu.tasks = executor, tasks
    try:
        yield
    finally:
        fmu.executor, fmu.tasks = before


@contextmanager
def calibration_executor(solver: SolverSpec) -> Iterator[Executor | None]:
    """The executor the spec's ``[solver]`` asks for: None (the serial fit) for workers = 0 without a
    scheduler; else the studies' executor (N local worker processes, or the scheduler's cluster)."""
    if not solver.workers and solver.scheduler is None:
        yield None
        return
    from milling_twin.orchestrator.study.executor import open_executor

    with open_executor(solver.workers or None, solver.scheduler) as executor:
        yield executor

