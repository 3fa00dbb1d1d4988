"""Parallel calibration: the starts of a multi-start fit, and the columns of a finite-difference Jacobian,
dispatched through the executor of the studies (:mod:`milling_twin.orchestrator.study.executor`: an embedded
dask ``LocalCluster``, N local worker processes, or an existing cluster), with the result of the serial fit
bit for bit.

``[solver] workers = N`` (0 or absent: the serial fit, in this process) or ``scheduler = "tcp://host:8786"``
(or a scheduler file) of the spec; ``milling-twin calibrate --workers N --scheduler ADDR``.

What runs where (the FMU finite-difference path, where each residual evaluation is a re-simulation of the
scenario; casadi objects built around Python callbacks do not pickle, so a worker builds its own from the
picklable pieces, :class:`~milling_twin.orchestrator.calibrate.fmu_outputs.FmuOutputs` and the pairs):

* more than one start: each start is a task (:func:`run_start`): the worker builds the residual model and the
  solver, runs the start (its Jacobians' columns one after the other) and sends back the start's outcome and the
  log of the evaluations it asked for; the outcomes are taken in start order, never in completion order, and
  each log is replayed into this process's cache in that order (:meth:`FmuOutputs.replay`), so the cache,
  the simulation count and the failures are those of the serial loop, and the second (noise-weighted) stage
  and the statistics that follow find what they would have found;
* one start, the second stage and the statistics: each finite-difference Jacobian's column simulations are
  tasks (:func:`~milling_twin.orchestrator.calibrate.fmu_outputs.evaluate`), submitted at once and combined
  in column order.

The same numbers come out because every evaluation is deterministic (the calibration checks that a re-run at
the initial values reproduces the initial run bit for bit) and every combination is made in a fixed order;
the seeded starts are drawn in this process. Only the wall times differ. The exact path (casadi derivatives of
the models/ equations, no simulation in the fit) keeps its starts in this process.
"""
from __future__ import annotations

import tempfile
from collections.abc import Iterator
from concurrent.futures import Executor, Future
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from milling_twin.orchestrator.calibrate.fmu_outputs import Access, FmuOutputs, JacobianAccess, fmu_residuals
from milling_twin.orchestrator.calibrate.lsq import LeastSquaresSolver, StartOutcome
from milling_twin.orchestrator.calibrate.pairing import Pairs
from milling_twin.orchestrator.calibrate.residuals import ResidualModel
from milling_twin.orchestrator.calibrate.spec import SolverSpec

__all__ = ["StartJob", "calibration_executor", "columns_on", "run_start", "solve_starts"]


@dataclass(frozen=True)
class StartJob:
    """What a worker needs to run starts of an FMU-path fit (picklable: no casadi object, no executor)."""

    fmu: FmuOutputs  # detached: no cache, no executor
    pairs: Pairs
    max_iterations: int
    tolerance: float
    hessian: str


def run_start(job: StartJob, x0: np.ndarray, p: np.ndarray,
              index: int) -> tuple[StartOutcome, list[Access | JacobianAccess]]:
    """A task: one start of the fit, in a worker process; its outcome and the evaluations it asked for."""
    fmu = job.fmu.detached()  # each start from an empty cache, whatever the executor shares between tasks
    model = fmu_residuals(fmu, job.pairs)
    lsq = LeastSquaresSolver(model.problem, max_iterations=job.max_iterations, tolerance=job.tolerance,
                             hessian=job.hessian)
    fmu.log = []
    # the start's runs in a folder of its own (starts run at once; the worker may be another machine)
    with tempfile.TemporaryDirectory(prefix="milling_twin_start_") as folder:
        fmu.work_dir = Path(folder)
        outcome = lsq.solve(x0, p, index=index)
    return outcome, fmu.log


def _fmu(model: ResidualModel) -> tuple[FmuOutputs, Pairs] | None:
    return model.origin if model.origin is not None and isinstance(model.origin[0], FmuOutputs) else None


def solve_starts(model: ResidualModel, lsq: LeastSquaresSolver, thetas: np.ndarray, p: np.ndarray,
                 executor: Executor, progress: bool = False) -> list[StartOutcome] | None:
    """Every start of ``thetas`` (rows, SI) as a task; the outcomes in start order. None: this model's starts
    cannot leave this process (the exact path), the caller runs them."""
    origin = _fmu(model)
    if origin is None:
        return None
    fmu, pairs = origin
    job = StartJob(fmu.detached(), pairs, lsq.max_iterations, lsq.tolerance, lsq.hessian)
    pending: list[StartOutcome | Future] = []
    starts: list[np.ndarray | None] = []
    for i, theta in enumerate(thetas):
        try:
            x0 = model.start(theta)
        except Exception as exc:  # noqa: BLE001 - the start's simulation failed: report, go on (as serial)
            pending.append(StartOutcome(i, np.asarray(theta) / model.scale(), "failed",
                                        f"the start's initial simulation failed: {type(exc).__name__}: {exc}"))
            starts.append(None)
            continue
        pending.append(executor.submit(run_start, job, x0, p, i))
        starts.append(x0)
    outcomes = []
    for i, item in enumerate(tqdm(pending, desc="calibration starts", unit="start", disable=not progress,
                                  leave=False)):
        if isinstance(item, StartOutcome):
            outcomes.append(item)
            continue
        try:
            outcome, log = item.result()
        except Exception as exc:  # noqa: BLE001 - a start that breaks (or whose worker dies) is reported
            outcomes.append(StartOutcome(i, starts[i], "failed",
                                         f"solver failed: {type(exc).__name__}: {exc}"))
            continue
        fmu.replay(log)
        outcomes.append(outcome)
    return outcomes


@contextmanager
def columns_on(model: ResidualModel, executor: Executor | None) -> Iterator[None]:
    """Within: the finite-difference Jacobians of ``model`` (FMU path) simulate their columns on ``executor``."""
    origin = _fmu(model) if executor is not None else None
    if origin is None:
        yield
        return
    fmu = origin[0]
    before, fmu.executor = fmu.executor, executor
    try:
        yield
    finally:
        fmu.executor = before


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

