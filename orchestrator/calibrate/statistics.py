"""Uncertainty of a least-squares estimate from the Jacobian at the optimum.

With residuals r (weighted, n of them) and J = dr/dtheta (n x p, SI parameters) at the estimate:

* ``sigma2 = SSR / (n - p)``, the residual variance (the weights make it 1 when they are the
  true noise levels);
* ``Cov = sigma2 * (J^T J)^-1``, computed through the SVD of J with columns normalised to unit
  length (J = Jn D, D = column norms), so that the units of the parameters do not matter;
* standard error ``sqrt(Cov_ii)``, 95 % confidence interval ``estimate -/+ t(0.975, n - p) * se``;
* correlation ``Cov_ij / sqrt(Cov_ii Cov_jj)``.

Residuals that are autocorrelated (a recording's noise is not white: the UMich spindle power swings with
a 0.3 s period) make ``sigma2 (J^T J)^-1`` too small. With ``hac`` (the group of every pair, e.g. its
recording segment, and a number of lags L) the covariance is the Newey-West sandwich
``(J^T J)^-1 S (J^T J)^-1`` with ``S = sum_l w_l (G_l + G_l^T)``, ``G_l = sum_t g_t g_(t-l)^T`` over
pairs t of the same group, ``g_t = J_t^T r_t`` (a pair's rows summed), ``w_0 = 1/2`` and Bartlett weights
``w_l = 1 - l / (L + 1)``; :func:`newey_west_lags` gives the usual L for n pairs.

Where the information on a parameter sits in a few samples (a spindle's run-up: five rows of a 10 Hz
recording fix its inertia) the asymptotics of the sandwich do not hold. :func:`block_bootstrap` resamples
blocks of consecutive pairs within their groups (moving-block bootstrap: the autocorrelation inside a block
is kept) and re-solves the weighted least-squares problem by one Gauss-Newton step from the estimate
(exact for outputs linear in the parameters, a linearisation otherwise); the replicates' standard deviation
is the standard error, and the interval is the estimate -/+ t * that error. Not the replicates' percentiles:
where one or two blocks hold all the information on a parameter (one run-up), the replicates take a few
discrete values, the estimate can sit at the edge of their 2.5-97.5 % range, and that range says little.

Runs of one machine can disagree beyond their own intervals: a run-up sampled at 10 Hz fixes a spindle's
inertia from five rows, and where the samples fall on the ramp differs from run to run. :func:`between_runs`
estimates that spread (DerSimonian-Laird random effects) from the runs' estimates and errors, and the
runs' common value with an error that includes it.

Flags (thresholds in :class:`~orchestrator.calibrate.spec.StatisticsSpec`):

* **not identifiable**: the parameter dominates (variance-decomposition proportion >= 0.5, the
  Belsley-Kuh-Welsch rule) a near-singular direction of Jn, i.e. one whose condition index
  ``s_max / s_j`` exceeds ``condition``; the data cannot tell that combination of parameters
  apart. A parameter that does not change the residuals at all is "no effect".
* **poorly determined**: standard error above ``relative_se`` of |estimate| (not said of an
  estimate at a bound).
* **correlated with X**: |correlation| above ``correlation``.
* **at lower/upper bound**: within 1e-6 of the range (or of the scale) from a bound; the
  interval then is not a valid confidence interval (the optimum is constrained).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy import stats as scipy_stats

from milling_twin.orchestrator.calibrate.parameters import Parameter
from milling_twin.orchestrator.calibrate.spec import StatisticsSpec

__all__ = ["BetweenRuns", "FitStatistics", "ParameterStatistics", "between_runs", "block_bootstrap",
           "fit_statistics", "hac_meat", "newey_west_lags", "with_intervals"]


@dataclass(frozen=True)
class ParameterStatistics:
    name: str
    estimate: float
    standard_error: float
    ci_low: float
    ci_high: float
    at_bound: str | None  # "lower", "upper" or None
    flags: tuple[str, ...]

    @property
    def identifiable(self) -> bool:
        return not any(f.startswith(("not identifiable", "no effect")) for f in self.flags) and self.at_bound is None

    def covers(self, value: float) -> bool:
        return self.ci_low <= value <= self.ci_high


@dataclass(frozen=True)
class FitStatistics:
    n_residuals: int
    n_parameters: int
    dof: int
    ssr: float
    sigma2: float
    t_quantile: float
    covariance: np.ndarray
    correlation: np.ndarray
    singular_values: np.ndarray  # of the column-normalised Jacobian, descending
    condition_indices: np.ndarray
    directions: np.ndarray  # right singular vectors (columns), same order
    parameters: tuple[ParameterStatistics, ...]

    def by_name(self, name: str) -> ParameterStatistics:
        return next(p for p in self.parameters if p.name == name)


def newey_west_lags(n: int) -> int:
    """The Newey-West (1994) rule of thumb for the lags of the Bartlett kernel: floor(4 (n/100)^(2/9))."""
    return int(math.floor(4.0 * (max(n, 1) / 100.0) ** (2.0 / 9.0)))


def hac_meat(jacobian: np.ndarray, residual: np.ndarray, groups: np.ndarray, lags: int) -> np.ndarray:
    """``S`` of the Newey-West sandwich (module text): rows are pair-major (``len(residual) / len(groups)``
    outputs per pair); lags never reach across a change of group."""
    J = np.asarray(jacobian, dtype=float)
    r = np.asarray(residual, dtype=float).ravel()
    groups = np.asarray(groups)
    n_pairs = groups.size
    if n_pairs == 0:
        return np.zeros((J.shape[1], J.shape[1]))
    n_out = r.size // n_pairs
    g = (J * r[:, None]).reshape(n_pairs, n_out, J.shape[1]).sum(axis=1)
    meat = g.T @ g
    for lag in range(1, min(lags, n_pairs - 1) + 1):
        same = groups[lag:] == groups[:-lag]
        cross = g[lag:][same].T @ g[:-lag][same]
        meat += (1.0 - lag / (lags + 1.0)) * (cross + cross.T)
    return meat


def block_bootstrap(jacobian: np.ndarray, residual: np.ndarray, estimates: Sequence[float], groups: np.ndarray,
                    block: int, replicates: int, seed: int = 0) -> np.ndarray:
    """Replicates (replicates x parameters, SI) of the estimates: blocks of up to ``block`` consecutive pairs,
    cut at every change of group, drawn with replacement; one Gauss-Newton step of the weighted problem from
    ``estimates`` (module text). Rows are pair-major, as for :func:`hac_meat`."""
    J = np.asarray(jacobian, dtype=float)
    r = np.asarray(residual, dtype=float).ravel()
    groups = np.asarray(groups)
    n_pairs = groups.size
    n_out = r.size // max(n_pairs, 1)
    start = np.ones(n_pairs, dtype=bool)
    if n_pairs:
        position = np.zeros(n_pairs, dtype=int)
        for k in range(1, n_pairs):  # position inside the current block
            same = groups[k] == groups[k - 1] and position[k - 1] + 1 < block
            position[k] = position[k - 1] + 1 if same else 0
        start = position == 0
    index = np.cumsum(start) - 1  # block of every pair
    n_blocks = int(index[-1]) + 1 if n_pairs else 0
    rng = np.random.default_rng(seed)
    theta = np.asarray(estimates, dtype=float)
    out = np.empty((replicates, theta.size))
    for b in range(replicates):
        counts = np.bincount(rng.integers(0, n_blocks, n_blocks), minlength=n_blocks).astype(float)
        w = np.repeat(counts[index], n_out)
        out[b] = theta - np.linalg.pinv(J.T @ (J * w[:, None])) @ (J.T @ (w * r))
    return out


@dataclass(frozen=True)
class BetweenRuns:
    """One parameter estimated on several runs (random effects, DerSimonian-Laird): the runs' common mean and
    its standard error, the spread ``tau`` of the runs' own values about it (what one run's interval cannot
    know: the run-to-run variation of the machine, its setup, or of how the sampling caught a short event), and
    ``i2``, the share of the estimates' spread that ``tau`` explains (0: the runs agree within their errors)."""

    mean: float
    standard_error: float
    tau: float
    i2: float
    runs: int

    def interval(self, estimate: float, standard_error: float) -> tuple[float, float]:
        """A run's 95 % interval widened by the spread between runs."""
        half = 1.959963984540054 * math.sqrt(standard_error ** 2 + self.tau ** 2)
        return estimate - half, estimate + half


def between_runs(estimates: Sequence[float], standard_errors: Sequence[float]) -> BetweenRuns:
    """DerSimonian-Laird random-effects estimate from per-run ``estimates`` and their ``standard_errors``
    (at least two runs with positive finite errors)."""
    y = np.asarray(estimates, dtype=float)
    se = np.asarray(standard_errors, dtype=float)
    if y.size < 2 or not np.all(np.isfinite(se) & (se > 0)):
        raise ValueError(f"between_runs needs at least two runs with positive finite standard errors, got {se!r}")
    w = 1.0 / se ** 2
    fixed = float(np.sum(w * y) / np.sum(w))
    q = float(np.sum(w * (y - fixed) ** 2))
    dof = y.size - 1
    c = float(np.sum(w) - np.sum(w ** 2) / np.sum(w))
    tau2 = max(0.0, (q - dof) / c) if c > 0 else 0.0
    w_star = 1.0 / (se ** 2 + tau2)
    mean = float(np.sum(w_star * y) / np.sum(w_star))
    i2 = max(0.0, (q - dof) / q) if q > 0 else 0.0
    return BetweenRuns(mean, float(math.sqrt(1.0 / np.sum(w_star))), math.sqrt(tau2), i2, int(y.size))


def with_intervals(statistics: FitStatistics, replicates: np.ndarray) -> FitStatistics:
    """``statistics`` with every parameter's standard error from bootstrap ``replicates`` (their standard
    deviation) and its 95 % interval the estimate -/+ t * that error (module text); flags are kept, and so is the
    infinite interval of a parameter without finite variance (the minimum-norm step would look precise)."""
    se = np.std(replicates, axis=0, ddof=1)
    t = statistics.t_quantile if np.isfinite(statistics.t_quantile) else 1.959963984540054
    parameters = tuple(p if not np.isfinite(p.standard_error) else
                       ParameterStatistics(p.name, p.estimate, float(se[j]), p.estimate - t * float(se[j]),
                                           p.estimate + t * float(se[j]), p.at_bound, p.flags)
                       for j, p in enumerate(statistics.parameters))
    return FitStatistics(statistics.n_residuals, statistics.n_parameters, statistics.dof, statistics.ssr,
                         statistics.sigma2, statistics.t_quantile, np.cov(replicates, rowvar=False).reshape(
                             len(parameters), len(parameters)), statistics.correlation, statistics.singular_values,
                         statistics.condition_indices, statistics.directions, parameters)


def fit_statistics(jacobian: np.ndarray, residual: np.ndarray, estimates: Sequence[float],
                   parameters: Sequence[Parameter], thresholds: StatisticsSpec | None = None, *,
                   n_residuals: int | None = None, extra_ssr: float = 0.0,
                   hac: tuple[np.ndarray, int] | None = None) -> FitStatistics:
    """Statistics of ``estimates`` (SI) from the weighted ``residual`` and ``jacobian`` = dr/dtheta (SI).
    Binned data: ``n_residuals`` samples stand behind the rows, ``extra_ssr`` is their within-bin part.
    ``hac``: (group of every pair, lags): the autocorrelation-consistent covariance (module text)."""
    thresholds = thresholds or StatisticsSpec()
    J = np.asarray(jacobian, dtype=float)
    r = np.asarray(residual, dtype=float).ravel()
    p = J.shape[1]
    n = int(n_residuals) if n_residuals is not None else J.shape[0]
    est = np.asarray(estimates, dtype=float)
    dof = n - p
    ssr = float(r @ r) + float(extra_ssr)
    sigma2 = ssr / dof if dof > 0 else math.nan
    t = float(scipy_stats.t.ppf(0.975, dof)) if dof > 0 else math.nan
    norms = np.linalg.norm(J, axis=0)
    effect = norms > 0
    Jn = np.where(effect, J / np.where(effect, norms, 1.0), 0.0)
    _, s, vt = np.linalg.svd(Jn, full_matrices=False)
    v = vt.T
    s_max = s[0] if s.size and s[0] > 0 else 1.0
    with np.errstate(divide="ignore"):
        condition = np.where(s > 0, s_max / np.where(s > 0, s, 1.0), np.inf)
    singular = s <= s_max * 1e-13
    inv_s2 = np.where(singular, 0.0, 1.0 / np.where(singular, 1.0, s) ** 2)
    cov_n = (v * inv_s2) @ v.T
    scale = np.where(effect, 1.0 / np.where(effect, norms, 1.0), 0.0)
    bread = cov_n * np.outer(scale, scale)  # (J^T J)^-1 on the identifiable directions
    cov = bread @ hac_meat(J, r, *hac) @ bread if hac is not None else sigma2 * bread
    # a parameter that loads on an exactly singular direction (or has no effect) has no finite variance
    unbounded = (~effect) | (np.abs(v[:, singular]) > 1e-8).any(axis=1)
    var = np.where(unbounded, np.inf, np.diag(cov))
    se = np.sqrt(np.maximum(var, 0.0))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.sqrt(np.outer(np.diag(cov), np.diag(cov)))
    corr[unbounded, :] = np.nan
    corr[:, unbounded] = np.nan
    np.fill_diagonal(corr, 1.0)
    # variance-decomposition proportions (Belsley, Kuh, Welsch)
    phi = v ** 2 / np.maximum(s, s_max * 1e-13)[None, :] ** 2
    proportions = phi / np.maximum(phi.sum(axis=1, keepdims=True), 1e-300)
    results = []
    for j, q in enumerate(parameters):
        flags: list[str] = []
        if not effect[j]:
            flags.append("no effect on the residuals")
        else:
            weak = [k for k in range(len(s)) if condition[k] > thresholds.condition and proportions[j, k] >= 0.5]
            if weak:
                k = weak[0]
                flags.append(f"not identifiable (near-singular direction, condition index "
                             f"{condition[k]:.3g})")
        tol = 1e-6 * min(q.upper - q.lower, q.scale) if math.isfinite(q.upper - q.lower) else 1e-6 * q.scale
        bound = "lower" if est[j] - q.lower <= tol else "upper" if q.upper - est[j] <= tol else None
        if bound is None and np.isfinite(se[j]) and se[j] > thresholds.relative_se * abs(est[j]):
            flags.append(f"poorly determined (se {100 * se[j] / abs(est[j]) if est[j] else math.inf:.3g} %)")
        for k in range(p):
            if k != j and np.isfinite(corr[j, k]) and abs(corr[j, k]) > thresholds.correlation:
                flags.append(f"correlated with {parameters[k].name} ({corr[j, k]:+.3f})")
        if bound:
            flags.append(f"at {bound} bound")
        half = t * se[j]
        results.append(ParameterStatistics(q.name, float(est[j]), float(se[j]), float(est[j] - half),
                                           float(est[j] + half), bound, tuple(flags)))
    return FitStatistics(n, p, dof, ssr, sigma2, t, cov, corr, s, condition, v, tuple(results))
