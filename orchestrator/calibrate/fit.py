"""Multi-start fit of a residual model, noise weighting, and the statistics of the best estimate.

1. Every output's residuals are divided by a noise level sigma_o and multiplied by sqrt(weight_o):
   the spec's ``sigma`` when given, else (first stage) the RMS of the recorded values.
2. The solver (lsq: IPOPT, or Levenberg-Marquardt on the FMU path) runs from each start (the initial
   values, then drawn ones); a start that fails is reported with its cause and the next one runs.
   The best converged start (lowest objective) wins; if none converged, the best that ran out of iterations is taken and said so.
3. With ``noise = "estimate"`` and more than one output, sigma_o becomes each output's residual
   RMS at the first-stage optimum and the fit is repeated from it (two-stage weighted least
   squares: the residuals of every output then have unit variance, as the statistics assume).
4. Standard errors, intervals, correlations and flags: :mod:`milling_twin.orchestrator.calibrate.statistics`.
"""
from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from concurrent.futures import Executor
from dataclasses import dataclass

import numpy as np
from tqdm import tqdm

from milling_twin.orchestrator.calibrate.errors import CalibrationError
from milling_twin.orchestrator.calibrate.lsq import LeastSquaresSolver, StartOutcome, with_algorithm
from milling_twin.orchestrator.calibrate.parallel import columns_on, solve_starts
from milling_twin.orchestrator.calibrate.parameters import Parameter, draw_starts
from milling_twin.orchestrator.calibrate.residuals import EXACT, ResidualModel
from milling_twin.orchestrator.calibrate.spec import SolverSpec, StatisticsSpec
from milling_twin.orchestrator.calibrate.statistics import FitStatistics, fit_statistics

__all__ = ["FitOutcome", "fit", "initial_sigma"]


@dataclass
class FitOutcome:
    parameters: tuple[Parameter, ...]
    theta: np.ndarray  # SI estimates
    starts: list[StartOutcome]
    best: StartOutcome
    refit: StartOutcome | None  # second stage (noise = "estimate")
    statistics: FitStatistics
    sigma: np.ndarray  # per-output noise level used in the final weights (SI)
    weights: np.ndarray  # per-output user weights
    solve_time: float  # all starts and the second stage, s
    note: str = ""
    derivatives: str = EXACT  # the residual model's path: exact derivatives or FMU finite differences

    def estimate(self, name: str) -> float:
        return float(self.theta[[q.name for q in self.parameters].index(name)])


def initial_sigma(recorded: np.ndarray, given: Sequence[float | None]) -> np.ndarray:
    """The first-stage noise level per output: the given sigma, else the RMS of the recorded values."""
    rms = np.sqrt(np.mean(np.asarray(recorded, dtype=float) ** 2, axis=0)) if len(recorded) else np.ones(len(given))
    return np.array([g if g is not None else (r if r > 0 else 1.0) for g, r in zip(given, rms)])


def _pick(outcomes: list[StartOutcome]) -> tuple[StartOutcome, str]:
    ok = [o for o in outcomes if o.converged]
    if ok:
        return min(ok, key=lambda o: o.objective), ""
    partial = [o for o in outcomes if o.status == "not converged"]
    if partial:
        best = min(partial, key=lambda o: o.objective)
        return best, f"no start converged; the best start that ran out of iterations ({best.index}) is used"
    causes = "; ".join(f"start {o.index}: {o.message}" for o in outcomes)
    raise CalibrationError(f"every start failed: {causes}")


def fit(model: ResidualModel, recorded: np.ndarray, *, weights: Sequence[float], sigma: Sequence[float | None],
        solver: SolverSpec, statistics: StatisticsSpec, progress: bool = False,
        lsq: LeastSquaresSolver | None = None, starts: np.ndarray | None = None,
        strategy: Callable[[LeastSquaresSolver, np.ndarray, np.ndarray, int], StartOutcome] | None = None,
        executor: Executor | None = None) -> FitOutcome:
    """Fit ``model`` to ``recorded`` (pairs x outputs). ``lsq``: a solver built for this model
    earlier (synthetic repeats); ``starts`` (rows of SI parameters): instead of the drawn ones;
    ``strategy(lsq, x0, p, index)``: how one start is solved (default: one IPOPT run); ``executor``: where
    the simulations of the FMU path run, the starts (more than one) at once and a Jacobian's columns in
    ``solver.workers`` tasks (0: one each) (:mod:`milling_twin.orchestrator.calibrate.parallel`: the same result
    as without, bit for bit)."""
    with columns_on(model, executor, solver.workers or None):
        return _fit(model, recorded, weights, sigma, solver, statistics, progress, lsq, starts, strategy, executor)


def _fit(model: ResidualModel, recorded: np.ndarray, weights: Sequence[float], sigma: Sequence[float | None],
         solver: SolverSpec, statistics: StatisticsSpec, progress: bool, lsq: LeastSquaresSolver | None,
         starts: np.ndarray | None,
         strategy: Callable[[LeastSquaresSolver, np.ndarray, np.ndarray, int], StartOutcome] | None,
         executor: Executor | None) -> FitOutcome:
    t0 = time.perf_counter()
    if lsq is None:
        try:
            problem = with_algorithm(model.problem, solver.algorithm)
        except ValueError as exc:
            raise CalibrationError(str(exc)) from None
        lsq = LeastSquaresSolver(problem, max_iterations=solver.max_iterations, tolerance=solver.tolerance,
                                 hessian=solver.hessian)
    solve = strategy or (lambda s, x0, data, index: s.solve(x0, data, index=index))
    user = np.asarray(weights, dtype=float)
    noise = initial_sigma(recorded, sigma)
    p = model.data_vector(recorded, np.sqrt(user) / noise)
    thetas = starts if starts is not None else draw_starts(model.parameters, solver.starts, solver.seed)
    parallel = (solve_starts(model, lsq, thetas, p, executor, progress, solver.workers or None)
                if executor is not None and strategy is None and len(thetas) > 1 else None)
    outcomes = parallel if parallel is not None else []
    for i, theta in enumerate(tqdm(thetas if parallel is None else [], desc="calibration starts", unit="start",
                                   disable=not progress, leave=False)):
        try:
            x0 = model.start(theta)
        except Exception as exc:  # noqa: BLE001 - the start's simulation failed: report, go on
            outcomes.append(StartOutcome(i, np.asarray(theta) / model.scale(), "failed",
                                         f"the start's initial simulation failed: {type(exc).__name__}: {exc}"))
            continue
        try:
            outcomes.append(solve(lsq, x0, p, i))
        except Exception as exc:  # noqa: BLE001 - a start that breaks is reported, the next one runs
            outcomes.append(StartOutcome(i, x0, "failed", f"solver failed: {type(exc).__name__}: {exc}"))
    best, note = _pick(outcomes)
    refit = None
    final = best
    if solver.noise == "estimate" and model.n_outputs > 1 and all(s is None for s in sigma):
        noise = model.residual_rms(model.theta(best.x), recorded)
        noise = np.where(noise > 0, noise, 1.0)
        p = model.data_vector(recorded, np.sqrt(user) / noise)
        refit = solve(lsq, best.x, p, len(outcomes))
        if refit.x is not None and refit.status != "failed":
            final = refit
        else:
            note = (note + "; " if note else "") + f"the second (noise-weighted) stage failed: {refit.message}"
    # IPOPT may end a hair outside a bound (its bound relaxation); the FMU's range checks would refuse it
    theta = np.clip(model.theta(final.x), [q.lower for q in model.parameters], [q.upper for q in model.parameters])
    r, jac = model.residual_jacobian(theta, p)
    stats = fit_statistics(jac, r, theta, model.parameters, statistics, n_residuals=model.n_samples,
                           extra_ssr=model.extra_ssr(p[-model.n_outputs:]))
    return FitOutcome(model.parameters, theta, outcomes, best, refit, stats, noise, user,
                      time.perf_counter() - t0, note, model.derivatives)
