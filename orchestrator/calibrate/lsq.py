"""Bounded nonlinear least squares with casadi's IPOPT, one solver for many starts and data sets.

The problem: minimise ``0.5*||r(x, p)||^2`` subject to ``g(x, p) = 0`` and ``lbx <= x <= ubx``,
where ``x`` is the scaled decision vector (the first ``n_parameters`` entries are the fitted
parameters divided by their scales; the rest, for multiple shooting, the scaled shooting-node
states) and ``p`` the data (recorded values and residual weights), so that one compiled solver
serves every start and every synthetic repeat.

Hessian: ``"gauss-newton"`` passes IPOPT ``lam_f * J^T J`` (J = dr/dx) as the Hessian of the
Lagrangian (generalised Gauss-Newton: the curvature of r and of the shooting constraints is
left out); ``"exact"`` lets casadi differentiate twice.

Algorithm (``[solver].algorithm``, :func:`with_algorithm`): IPOPT, or a projected Levenberg-Marquardt method
that needs one Jacobian per iteration and none for a rejected step: a linear problem converges in one or two
iterations where the interior-point method takes 15 or more (its barrier parameter must go to zero). The
latter is the default where Jacobians are dear: residuals evaluated by simulation (each Jacobian costs one
simulation per parameter, see :mod:`milling_twin.orchestrator.calibrate.fmu_outputs`) and the slot-forces
waveform (a force mapped over 1,000 angles).
Bounds: a parameter at a bound whose gradient points outwards is held there for the step, the others
take the damped Gauss-Newton step ``(A^T A + lambda diag(A^T A)) dx = -A^T r``, projected on the
bounds; the step is accepted when the objective decreases (lambda / 10), else lambda * 10. Converged:
relative decrease of the objective below ``tolerance``, or no decrease possible (lambda beyond 1e12)
with a projected step below 1e-8 of the parameters' size (what remains is the rounding of the
evaluations). Equality constraints (multiple shooting) need IPOPT.

BLAS threads: the Levenberg-Marquardt iterations run with numpy's bundled OpenBLAS on one thread
(:mod:`milling_twin.models.blas_threads`). Their matrices are small (1,500 x 34 on the slot forces), and OpenBLAS's
threads, which spin between calls, made each QR factoring of the step 10 to 25 times slower than one thread
whenever another process kept a core busy.

Robustness: before a start is handed to IPOPT the residuals and their Jacobian are evaluated at
it; a non-finite value is reported with the residual and the parameter it concerns (or, when the
model is evaluated by simulation, the simulation's failure) and the start is skipped. IPOPT failures
(its return status) and exceptions are reported with their cause, and with the first failed model
evaluation of the run if any; either way the next start runs.
"""
from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace

import casadi as ca
import numpy as np

from milling_twin.models.blas_threads import one_blas_thread

__all__ = ["ALGORITHMS", "LeastSquaresProblem", "LeastSquaresSolver", "StartOutcome", "SUCCESS", "with_algorithm"]

SUCCESS = ("Solve_Succeeded", "Solved_To_Acceptable_Level")
ALGORITHMS = ("ipopt", "levenberg-marquardt")


@dataclass(frozen=True)
class LeastSquaresProblem:
    x: ca.MX  # decision vector symbol (scaled)
    p: ca.MX  # data symbol
    residual: ca.MX
    constraints: ca.MX
    lbx: np.ndarray
    ubx: np.ndarray
    n_parameters: int
    # labels for messages: residual index -> "power.P_total at t = 3.1 s", variable index -> name
    describe_residual: Callable[[int], str] = field(default=lambda i: f"residual {i}")
    describe_variable: Callable[[int], str] = field(default=lambda j: f"variable {j}")
    # causes of failed model evaluations so far (the FMU path: a simulation that failed gives NaN outputs)
    failures: Callable[[], list[str]] | None = None
    # keep every evaluation inside the bounds (IPOPT relaxes them by 1e-8 by default): for models evaluated by
    # the FMUs, which refuse a parameter outside its range
    strict_bounds: bool = False
    algorithm: str = "ipopt"  # or "levenberg-marquardt" (no constraints)


@dataclass
class StartOutcome:
    index: int
    x0: np.ndarray  # scaled start
    status: str  # "converged", "not converged", "failed"
    message: str  # IPOPT return status, or the cause of the failure
    x: np.ndarray | None = None
    objective: float = float("nan")
    iterations: int = 0
    wall_time: float = 0.0
    trace: dict[str, list[float]] = field(default_factory=dict)

    @property
    def converged(self) -> bool:
        return self.status == "converged"


def with_algorithm(problem: LeastSquaresProblem, choice: str) -> LeastSquaresProblem:
    """``problem`` solved by ``choice`` (``[solver].algorithm``): "auto" keeps the problem's own (IPOPT, or
    Levenberg-Marquardt where the model set it: the FMU path, the slot-forces waveform), else one of
    :data:`ALGORITHMS`. A ValueError names the key when the choice cannot solve the problem."""
    if choice == "auto":
        return problem
    if choice not in ALGORITHMS:
        raise ValueError(f"[solver].algorithm = {choice!r}: expected \"auto\" or one of {', '.join(ALGORITHMS)}")
    if choice == "levenberg-marquardt" and problem.constraints.numel():
        raise ValueError('[solver].algorithm = "levenberg-marquardt" takes no constraints: this model has states '
                         'fitted by multiple shooting (its continuity constraints need IPOPT); set [solver].shooting '
                         '= "single" or the algorithm to "ipopt" or "auto"')
    return replace(problem, algorithm=choice)


class LeastSquaresSolver:
    """The solver of a problem (its ``algorithm``: IPOPT, built once, or the Levenberg-Marquardt method);
    :meth:`solve` runs one start."""

    def __init__(self, problem: LeastSquaresProblem, *, max_iterations: int = 200, tolerance: float = 1e-10,
                 hessian: str = "gauss-newton", expand: bool = False) -> None:
        """``expand``: IPOPT evaluates the problem as one SX graph: faster for a graph of many small MX
        operations, but slow to build for a large one (a slot-forces fit of five recordings with its force
        mapped over 1,000 angles: 70 s to build, against 0.1 s for its MX graph of a few mapped SX functions,
        whose evaluations took 10 % longer)."""
        self.problem = problem
        x, p, r = problem.x, problem.p, problem.residual
        jac = ca.jacobian(r, x)
        self.check = ca.Function("lsq_check", [x, p], [r, jac])
        self.residual = ca.Function("lsq_residual", [x, p], [r])
        if expand:
            self.check, self.residual = self.check.expand(), self.residual.expand()
        self.max_iterations, self.tolerance, self.hessian = max_iterations, tolerance, hessian
        if problem.algorithm not in ALGORITHMS:
            raise ValueError(f"unknown least-squares algorithm {problem.algorithm!r}")
        if problem.algorithm == "levenberg-marquardt" and problem.constraints.numel():
            raise ValueError("the Levenberg-Marquardt method takes no constraints (multiple shooting needs IPOPT)")
        n_g = problem.constraints.numel()
        self.lbg = self.ubg = np.zeros(n_g)
        self.nlp = None
        if problem.algorithm == "ipopt":
            self.nlp = self._ipopt(jac, expand)

    @property
    def name(self) -> str:
        """The method, as reports name it."""
        return "IPOPT" if self.problem.algorithm == "ipopt" else "Levenberg-Marquardt"

    def _ipopt(self, jac: ca.MX, expand: bool) -> ca.Function:
        problem, hessian = self.problem, self.hessian
        x, p, r = problem.x, problem.p, problem.residual
        nlp = {"x": x, "p": p, "f": 0.5 * ca.dot(r, r), "g": problem.constraints}
        options: dict = {"print_time": False, "error_on_fail": False,
                         "ipopt": {"print_level": 0, "sb": "yes", "max_iter": self.max_iterations,
                                   "tol": self.tolerance, "acceptable_tol": max(self.tolerance * 1e3, 1e-8),
                                   "acceptable_iter": 10}}
        if expand:
            options["expand"] = True
        if problem.strict_bounds:
            options["ipopt"]["bound_relax_factor"] = 0.0
            options["ipopt"]["honor_original_bounds"] = "yes"
        if hessian == "gauss-newton":
            lam_f = ca.MX.sym("lam_f")
            lam_g = ca.MX.sym("lam_g", problem.constraints.numel())
            hess = lam_f * ca.mtimes(jac.T, jac)
            options["hess_lag"] = ca.Function("nlp_hess_l", [x, p, lam_f, lam_g], [ca.triu(hess)],
                                              ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"])
            if expand:
                options["hess_lag"] = options["hess_lag"].expand()
        return ca.nlpsol("calibration", "ipopt", nlp, options)

    def _precheck(self, x0: np.ndarray, p: np.ndarray) -> str | None:
        r, jac = self.residual_and_jacobian(x0, p)
        bad = np.flatnonzero(~np.isfinite(r))
        if bad.size:
            return (f"the model gives a non-finite value ({r[bad[0]]}) for {self.problem.describe_residual(int(bad[0]))} "
                    f"({bad.size} residuals non-finite)")
        rows, cols = np.nonzero(~np.isfinite(jac))
        if rows.size:
            rows, cols = self._symbolic_nonfinite(x0, p, rows, cols)
            names = sorted({self.problem.describe_variable(int(c)) for c in cols})
            return (f"the derivative of {self.problem.describe_residual(int(rows[0]))} with respect to "
                    f"{self.problem.describe_variable(int(cols[0]))} is {jac[rows[0], cols[0]]} "
                    f"({rows.size} non-finite derivative entries, with respect to {', '.join(names)}); if a data "
                    "input at a boundary value (such as 0) makes it undefined, give that input a floor in the "
                    "spec's [inputs] table")
        return None

    def _symbolic_nonfinite(self, x0: np.ndarray, p: np.ndarray, rows: np.ndarray,
                            cols: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Which entries of the Jacobian are non-finite, from a symbolic (SX) Jacobian: the numeric one
        combines columns (graph colouring), so one undefined partial derivative (e.g. log(0)*0) spreads
        to the others. Only run when something is wrong; falls back to the numeric entries."""
        try:
            residual = ca.Function("lsq_residual", [self.problem.x, self.problem.p], [self.problem.residual]).expand()
            xs, ps = ca.SX.sym("x", self.problem.x.numel()), ca.SX.sym("p", self.problem.p.numel())
            jac = ca.Function("lsq_sx_jacobian", [xs, ps], [ca.jacobian(residual(xs, ps), xs)])
            dense = np.asarray(jac(x0, p), dtype=float)
        except Exception:  # noqa: BLE001 - the diagnosis is best effort
            return rows, cols
        bad_rows, bad_cols = np.nonzero(~np.isfinite(dense))
        return (bad_rows, bad_cols) if bad_rows.size else (rows, cols)

    def solve(self, x0: np.ndarray, p: np.ndarray, index: int = 0, lbx: np.ndarray | None = None,
              ubx: np.ndarray | None = None) -> StartOutcome:
        """One IPOPT run from ``x0`` (scaled); ``lbx``/``ubx`` replace the problem's bounds (equal
        bounds fix a variable)."""
        t0 = time.perf_counter()
        lbx = self.problem.lbx if lbx is None else lbx
        ubx = self.problem.ubx if ubx is None else ubx
        x0 = np.clip(np.asarray(x0, dtype=float), lbx, ubx)
        failed_before = len(self.problem.failures()) if self.problem.failures else 0
        try:
            cause = self._precheck(x0, p)
        except Exception as exc:  # noqa: BLE001 - any evaluation failure is reported, the run goes on
            cause = f"model evaluation failed: {type(exc).__name__}: {exc}"
        new_failures = self._failures_since(failed_before)
        if cause is not None and new_failures:
            cause = f"model evaluation failed: {new_failures[0]}"
        if cause is not None:
            return StartOutcome(index, x0, "failed", cause, wall_time=time.perf_counter() - t0)
        if self.problem.algorithm == "levenberg-marquardt":
            try:
                with one_blas_thread():  # module text: small matrices
                    outcome = self._levenberg_marquardt(x0, p, index, lbx, ubx)
            except Exception as exc:  # noqa: BLE001
                outcome = StartOutcome(index, x0, "failed", f"solver failed: {type(exc).__name__}: {exc}")
            new_failures = self._failures_since(failed_before)
            if new_failures:
                outcome.message += (f"; {len(new_failures)} model evaluation(s) failed during the iterations (the "
                                    f"step was shortened), the first: {new_failures[0]}")
            outcome.wall_time = time.perf_counter() - t0
            return outcome
        try:
            sol = self.nlp(x0=x0, p=p, lbx=lbx, ubx=ubx, lbg=self.lbg, ubg=self.ubg)
            stats = self.nlp.stats()
        except Exception as exc:  # noqa: BLE001
            return StartOutcome(index, x0, "failed", f"solver failed: {type(exc).__name__}: {exc}",
                                wall_time=time.perf_counter() - t0)
        status = str(stats.get("return_status", "unknown"))
        new_failures = self._failures_since(failed_before)
        if new_failures:
            status += (f"; {len(new_failures)} model evaluation(s) failed during the iterations (IPOPT backs off "
                       f"from such trial points), the first: {new_failures[0]}")
        iterations = stats.get("iterations", {})
        trace = {k: [float(v) for v in iterations.get(k, [])] for k in ("obj", "inf_pr", "inf_du")}
        x = np.asarray(sol["x"], dtype=float).ravel()
        objective = float(sol["f"])
        code = status.split(";", 1)[0]
        if code in SUCCESS and np.all(np.isfinite(x)) and np.isfinite(objective):
            state = "converged"
        elif np.all(np.isfinite(x)) and np.isfinite(objective) and code == "Maximum_Iterations_Exceeded":
            state = "not converged"
        else:
            state = "failed"
        return StartOutcome(index, x0, state, status, x if np.all(np.isfinite(x)) else None, objective,
                            int(stats.get("iter_count", 0)), time.perf_counter() - t0, trace)

    def _levenberg_marquardt(self, x: np.ndarray, p: np.ndarray, index: int, lbx: np.ndarray,
                             ubx: np.ndarray) -> StartOutcome:
        x0 = x
        r, jac = self.residual_and_jacobian(x, p)
        f = 0.5 * float(r @ r)
        trace = {"obj": [f]}
        lam = 1e-3
        status, state = "Maximum_Iterations_Exceeded", "not converged"
        iterations = 0
        factor = None
        while iterations < self.max_iterations:
            if factor is None:  # once per Jacobian: a rejected step only changes lambda
                g = jac.T @ r
                held = ((x <= lbx) & (g > 0)) | ((x >= ubx) & (g < 0)) | (lbx == ubx)
                free = ~held
                a = jac[:, free]
                d = np.maximum(np.sum(a * a, axis=0), 1e-300)
                # ||A s + r|| = ||R s + Q^T r|| up to a constant (A = QR): each lambda's damped problem is then
                # as small as the free parameters, not as the residuals (1,500 of them on the slot forces)
                q, upper = np.linalg.qr(a)
                factor = free, d, upper, q.T @ r
            free, d, upper, projected = factor
            # the damped normal equations as a least-squares problem (better conditioned than forming A^T A)
            aug = np.vstack([upper, np.diag(np.sqrt(lam * d))])
            step = np.zeros_like(x)
            step[free] = np.linalg.lstsq(aug, -np.concatenate([projected, np.zeros(free.sum())]), rcond=None)[0]
            x_new = np.clip(x + step, lbx, ubx)
            moved = np.abs(x_new - x)
            r_new = self.residual_values(x_new, p)
            f_new = 0.5 * float(r_new @ r_new) if np.all(np.isfinite(r_new)) else np.inf
            if f_new < f:
                iterations += 1
                decrease = f - f_new
                x, f = x_new, f_new
                trace["obj"].append(f)
                lam = max(lam / 10, 1e-12)
                if decrease <= self.tolerance * max(f, 1e-300) or not free.any():
                    status, state = "Converged: relative decrease of the objective below the tolerance", "converged"
                    break
                r, jac = self.residual_and_jacobian(x, p)
                factor = None
            else:
                lam *= 10
                if lam > 1e12:
                    small = np.max(moved / np.maximum(np.abs(x), 1.0)) if moved.size else 0.0
                    if small <= 1e-8:
                        status, state = ("Converged: no further decrease (the objective is flat to the rounding of "
                                          "the evaluations)", "converged")
                    else:
                        status, state = "Stopped: no decrease along the damped steps", "not converged"
                    break
        return StartOutcome(index, x0, state, status, x, f, iterations, 0.0, trace)

    def residual_values(self, x: np.ndarray, p: np.ndarray) -> np.ndarray:
        return np.asarray(self.residual(x, p), dtype=float).ravel()

    def _failures_since(self, count: int) -> list[str]:
        return self.problem.failures()[count:] if self.problem.failures else []

    def residual_and_jacobian(self, x: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, jac = self.check(x, p)
        return np.asarray(r, dtype=float).ravel(), np.asarray(jac, dtype=float)
