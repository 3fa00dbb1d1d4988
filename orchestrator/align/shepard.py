"""Shepard (inverse-distance-weighted) interpolation over the ``neighbours`` nearest data points
(scipy cKDTree): ``f(x) = sum_i w_i f_i / sum_i w_i`` with ``w_i = 1 / d_i^power``; a query on
a data point returns its value."""
from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from milling_twin.orchestrator.align.errors import AlignmentError

__all__ = ["shepard"]


def shepard(points: np.ndarray, values: np.ndarray, query: np.ndarray, power: float = 2.0,
            neighbours: int = 8) -> np.ndarray:
    """Values (q, ...) at ``query`` (q, d) from ``values`` (k, ...) at ``points`` (k, d)."""
    points = np.asarray(points, dtype=np.float64)
    values = np.asarray(values, dtype=np.float64)
    query = np.asarray(query, dtype=np.float64)
    if points.ndim != 2 or query.ndim != 2 or points.shape[1] != query.shape[1]:
        raise AlignmentError(f"shepard: points {points.shape} and query {query.shape} must be "
                             f"(n, d) arrays of one dimension d")
    if values.shape[0] != points.shape[0]:
        raise AlignmentError(f"shepard: {values.shape[0]} values for {points.shape[0]} points")
    if points.shape[0] < 1 or power <= 0:
        raise AlignmentError("shepard: need at least one point and power > 0")
    k = min(int(neighbours), points.shape[0])
    dist, idx = cKDTree(points).query(query, k=k)
    dist, idx = dist.reshape(len(query), k), idx.reshape(len(query), k)
    exact = dist[:, 0] <= 1e-12 * (1.0 + np.abs(query).max())
    w = np.maximum(dist, 1e-100) ** -power
    w[exact] = 0.0
    w[exact, 0] = 1.0
    w /= w.sum(axis=1, keepdims=True)
    return np.einsum("qk,qk...->q...", w, values[idx])
