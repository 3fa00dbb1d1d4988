"""Weighted residuals of a model graph on paired data, as casadi least-squares problems.

Residual of output o at pair i: ``sqrt(c_i) * w_o * (y_model_o(theta; data_i) - y_recorded_io)``;
the recorded values and the weights are the NLP's data vector ``p`` (so one solver serves any data of
the same shape), ordered pair-major (all outputs of pair 0, then pair 1, ...). ``c_i`` is the number
of samples a pair stands for (1, except for binned data: a bin's mean with ``c`` samples gives the same
sum of squares as its samples up to the constant within-bin part, which :attr:`ResidualModel.within`
keeps for the statistics).

Stateless graphs map the sample function over the pairs. Dynamic graphs simulate the rows
0 .. K (K the last paired row) with ``step`` (casadi mapaccum) from the start states:

* single shooting: one rollout;
* multiple shooting: the rows are cut into intervals of ``shooting_interval`` steps; the state
  at the start of each interval is a decision variable (scaled by the state's size in the initial
  simulation), continuity ``x_end(interval i) = s(i+1)`` is an equality constraint, s(0) is fixed
  to the start states. Node states start from a simulation with the start's parameters.

Standard errors always use the single-shooting Jacobian (at the optimum the two coincide).
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np
import pandas as pd

from milling_twin.orchestrator.calibrate.graph import ModelGraph
from milling_twin.orchestrator.calibrate.lsq import LeastSquaresProblem
from milling_twin.orchestrator.calibrate.pairing import Pairs
from milling_twin.orchestrator.calibrate.parameters import Parameter

__all__ = ["EXACT", "ResidualModel", "build_residuals", "from_outputs"]

EXACT = "exact derivatives of the models/ equations (casadi)"


@dataclass
class ResidualModel:
    problem: LeastSquaresProblem
    parameters: tuple[Parameter, ...]
    n_outputs: int
    n_pairs: int
    simulate: ca.Function  # theta (SI) -> Y (outputs x pairs)
    single: ca.Function  # (theta SI, p) -> (r, dr/dtheta)
    node_start: ca.Function | None  # theta (SI) -> scaled node states (multiple shooting)
    counts: np.ndarray | None = None  # samples per pair (None: 1 each)
    within: np.ndarray | None = None  # per output: sum of squares of the samples about their bin mean
    derivatives: str = EXACT  # how the outputs and their Jacobian are computed (said in the report)
    keep_alive: object = None  # Python objects the casadi Functions call (callbacks): casadi holds no reference
    # what a worker process builds the model again from (parallel starts, orchestrator/calibrate/parallel.py):
    # the FMU path's (FmuOutputs, Pairs); None: the model's starts stay in this process
    origin: tuple | None = None

    @property
    def n_samples(self) -> int:
        """Residuals the pairs stand for (samples x outputs)."""
        return int(round((self.counts.sum() if self.counts is not None else self.n_pairs) * self.n_outputs))

    def extra_ssr(self, weights: np.ndarray) -> float:
        return float(np.sum(np.asarray(weights) ** 2 * self.within)) if self.within is not None else 0.0

    def residual_rms(self, theta: np.ndarray, recorded: np.ndarray) -> np.ndarray:
        """Per output: RMS of (model - recorded) over the samples the pairs stand for."""
        error2 = (self.predict(theta) - recorded) ** 2
        counts = self.counts if self.counts is not None else np.ones(self.n_pairs)
        within = self.within if self.within is not None else np.zeros(self.n_outputs)
        return np.sqrt((counts @ error2 + within) / counts.sum())

    def data_vector(self, recorded: np.ndarray, weights: Sequence[float]) -> np.ndarray:
        """p for recorded values (pairs x outputs) and per-output weights."""
        return np.concatenate([np.asarray(recorded, dtype=float).ravel(), np.asarray(weights, dtype=float)])

    def scale(self) -> np.ndarray:
        return np.array([q.scale for q in self.parameters])

    def start(self, theta: np.ndarray) -> np.ndarray:
        x = np.asarray(theta, dtype=float) / self.scale()
        if self.node_start is None:
            return x
        return np.concatenate([x, np.asarray(self.node_start(theta), dtype=float).ravel()])

    def theta(self, x: np.ndarray) -> np.ndarray:
        return np.asarray(x[: len(self.parameters)], dtype=float) * self.scale()

    def predict(self, theta: np.ndarray) -> np.ndarray:
        """Model outputs at the pairs, pairs x outputs."""
        return np.asarray(self.simulate(theta), dtype=float).reshape(self.n_outputs, self.n_pairs, order="F").T \
            if self.n_pairs else np.zeros((0, self.n_outputs))

    def residual_jacobian(self, theta: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        r, jac = self.single(theta, p)
        return np.asarray(r, dtype=float).ravel(), np.asarray(jac, dtype=float)


def _weighted(y: ca.MX, p: ca.MX, n_out: int, n: int, counts: np.ndarray | None = None) -> ca.MX:
    recorded = p[: n_out * n]
    weights = ca.repmat(p[n_out * n:], n, 1)
    if counts is not None:
        weights = weights * ca.DM(np.repeat(np.sqrt(counts), n_out))
    return weights * (ca.vec(y) - recorded)


def from_outputs(y_of, parameters: Sequence[Parameter], n_out: int, n: int, *, counts: np.ndarray | None = None,
                 within: np.ndarray | None = None, describe_residual=None, describe_variable=None) -> ResidualModel:
    """A stateless residual model from ``y_of(theta) -> outputs x pairs`` (casadi MX, theta SI)."""
    n_th = len(parameters)
    scale = np.array([q.scale for q in parameters])
    x_par = ca.MX.sym("x", n_th)
    p = ca.MX.sym("p", n_out * n + n_out)
    th_sym = ca.MX.sym("theta", n_th)
    r = _weighted(y_of(x_par * ca.DM(scale)), p, n_out, n, counts)
    extra = {k: v for k, v in (("describe_residual", describe_residual), ("describe_variable", describe_variable)) if v}
    problem = LeastSquaresProblem(x_par, p, r, ca.MX(0, 1), np.array([q.lower for q in parameters]) / scale,
                                  np.array([q.upper for q in parameters]) / scale, n_th, **extra)
    y_th = y_of(th_sym)
    r_th = _weighted(y_th, p, n_out, n, counts)
    return ResidualModel(problem, tuple(parameters), n_out, n, ca.Function("simulate", [th_sym], [ca.vec(y_th)]),
                         ca.Function("single", [th_sym, p], [r_th, ca.jacobian(r_th, th_sym)]), None,
                         None if counts is None else np.asarray(counts, dtype=float),
                         None if within is None else np.asarray(within, dtype=float))


def _describe(graph: ModelGraph, pairs: Pairs, parameters: Sequence[Parameter], n_params: int):
    n_out = len(graph.outputs)

    def residual(i: int) -> str:
        k, o = divmod(i, n_out)
        inputs = ", ".join(f"{c.ref} = {pairs.data[k, j]:.6g}" for j, c in enumerate(graph.data))
        return f"{graph.outputs[o]} at recorded t = {pairs.recorded_time[k]:.6g} s ({inputs})"

    def variable(j: int) -> str:
        return parameters[j].name if j < n_params else f"shooting-node state {j - n_params}"

    return residual, variable


def build_residuals(graph: ModelGraph, pairs: Pairs, parameters: Sequence[Parameter], results: pd.DataFrame,
                    shooting: str = "single", interval: int = 100) -> ResidualModel:
    """Residuals on ``pairs`` (one segment); ``results`` supplies the rows of dynamic models."""
    n, n_out, n_th = len(pairs), len(graph.outputs), len(parameters)
    scale = np.array([q.scale for q in parameters])
    x_par = ca.MX.sym("x", n_th)
    theta = x_par * ca.DM(scale)
    p = ca.MX.sym("p", n_out * n + n_out)
    th_sym = ca.MX.sym("theta", n_th)
    describe_residual, describe_variable = _describe(graph, pairs, parameters, n_th)
    if graph.dynamic is None:
        mapped = graph.sample.map(max(n, 1))
        D = ca.DM(pairs.data.T) if n else ca.DM.zeros(len(graph.data), 1)
        return from_outputs(lambda th: mapped(ca.repmat(th, 1, max(n, 1)), D)[:, :n], parameters, n_out, n,
                            describe_residual=describe_residual, describe_variable=describe_variable)

    dyn = graph.dynamic
    K = int(pairs.rows.max()) if n else 0
    cols = [c.ref for c in graph.data]
    D_rows = results[cols].to_numpy(dtype=float)[: K + 1].T if cols else np.zeros((0, K + 1))
    if D_rows.shape[1] < K + 1:
        raise ValueError(f"the results have {D_rows.shape[1]} rows, the pairs need {K + 1}")
    x0 = ca.DM(dyn.initial)
    n_x = dyn.initial.size
    rows = [int(r) for r in pairs.rows]

    def rollout(th: ca.MX) -> tuple[ca.MX, ca.MX]:
        """States (n_x x K) and outputs (n_out x K+1) of rows 0 .. K."""
        y0 = dyn.initial_outputs(x0, th, ca.DM(D_rows[:, :1]))
        if K == 0:
            return ca.MX(n_x, 0), y0
        roll = dyn.step.mapaccum("rollout", K)
        X, Y = roll(x0, ca.repmat(th, 1, K), ca.DM(D_rows[:, 1:]))
        return X, ca.horzcat(y0, Y)

    X_th, Y_th = rollout(th_sym)
    y_sel_th = Y_th[:, rows] if n else ca.MX(n_out, 0)
    r_th = _weighted(y_sel_th, p, n_out, n)
    simulate = ca.Function("simulate", [th_sym], [ca.vec(y_sel_th)])
    single = ca.Function("single", [th_sym, p], [r_th, ca.jacobian(r_th, th_sym)])
    states_at = ca.Function("states", [th_sym], [X_th])
    lbx = np.array([q.lower for q in parameters]) / scale
    ubx = np.array([q.upper for q in parameters]) / scale
    if shooting == "single" or K <= interval or n_x == 0:
        _, Y = rollout(theta)
        r = _weighted(Y[:, rows] if n else ca.MX(n_out, 0), p, n_out, n)
        problem = LeastSquaresProblem(x_par, p, r, ca.MX(0, 1), lbx, ubx, n_th, describe_residual, describe_variable)
        return ResidualModel(problem, tuple(parameters), n_out, n, simulate, single, None)

    M = interval
    n_int = math.ceil(K / M)
    pad = n_int * M - K
    D_steps = np.concatenate([D_rows[:, 1:], np.repeat(D_rows[:, -1:], pad, axis=1)], axis=1)
    x_initial = np.asarray(states_at(np.array([q.initial for q in parameters])), dtype=float)
    x_scale = np.maximum(np.max(np.abs(np.concatenate([x_initial, dyn.initial[:, None]], axis=1)), axis=1), 1e-300)
    x_scale = np.where(x_scale > 1e-300, x_scale, 1.0)
    z = ca.MX.sym("nodes", n_x * n_int)
    S = ca.reshape(z, n_x, n_int) * ca.repmat(ca.DM(x_scale), 1, n_int)
    interval_fn = dyn.step.mapaccum("interval", M).map(n_int)
    X, Y = interval_fn(S, ca.repmat(theta, 1, M * n_int), ca.DM(D_steps))
    y0 = dyn.initial_outputs(x0, theta, ca.DM(D_rows[:, :1]))
    Y_all = ca.horzcat(y0, Y)
    r = _weighted(Y_all[:, rows] if n else ca.MX(n_out, 0), p, n_out, n)
    ends = X[:, [(i + 1) * M - 1 for i in range(n_int - 1)]]
    g = ca.vec((ends - S[:, 1:]) / ca.repmat(ca.DM(x_scale), 1, n_int - 1))
    node_lb = np.full((n_x, n_int), -np.inf)
    node_ub = np.full((n_x, n_int), np.inf)
    node_lb[:, 0] = node_ub[:, 0] = dyn.initial / x_scale
    problem = LeastSquaresProblem(ca.vertcat(x_par, z), p, r, g, np.concatenate([lbx, node_lb.ravel(order="F")]),
                                  np.concatenate([ubx, node_ub.ravel(order="F")]), n_th, describe_residual,
                                  describe_variable)
    X_start = ca.horzcat(x0, X_th)[:, [i * M for i in range(n_int)]] / ca.repmat(ca.DM(x_scale), 1, n_int)
    node_start = ca.Function("node_start", [th_sym], [ca.vec(X_start)])
    return ResidualModel(problem, tuple(parameters), n_out, n, simulate, single, node_start)
