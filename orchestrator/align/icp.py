"""Point-to-plane ICP (iterative closest point) with scipy: nearest neighbours by cKDTree, the
linearised rigid update by least squares (scipy.linalg.lstsq), rotations by
scipy.spatial.transform.Rotation.

Each iteration pairs every source point (transformed so far) with its nearest target point,
drops pairs farther apart than ``max_distance``, and solves for the small rotation ``w`` and
translation ``t`` minimising ``sum_i ((p_i - q_i) . n_i + w . (p_i x n_i) + t . n_i)^2`` (n_i:
the target normal). Directions the data cannot fix (rotation about a cylinder's axis, sliding
along it, along a flat wall) get no motion: the minimum-norm least-squares solution, with
singular values below ``rcond`` times the largest (columns scaled alike) treated as zero.
Stops when the update moves no point by more than ``tolerance`` or after ``max_iterations``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import lstsq
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from milling_twin.orchestrator.align.errors import AlignmentError

__all__ = ["IcpResult", "icp"]


@dataclass(frozen=True)
class IcpResult:
    """``rotation`` (3, 3) and ``translation`` (3,): target ~ rotation @ source + translation.
    ``mean_distance`` (F): mean distance of the matched source points to the target surface
    (along the target normal); ``mean_point_distance``: mean distance to the matched target
    point; ``matched``: fraction of source points paired in the last iteration; ``rank``: rank
    of the last least-squares system (6 = fully determined)."""

    rotation: np.ndarray
    translation: np.ndarray
    mean_distance: float
    mean_point_distance: float
    matched: float
    iterations: int
    converged: bool
    rank: int

    def apply(self, points: np.ndarray) -> np.ndarray:
        return points @ self.rotation.T + self.translation


def icp(source: np.ndarray, target: np.ndarray, target_normals: np.ndarray,
        max_distance: float, max_iterations: int = 50, tolerance: float = 1e-7,
        min_overlap: float = 0.5, rcond: float = 0.05) -> IcpResult:
    """Register ``source`` (n, 3) to ``target`` (m, 3) with unit ``target_normals`` (m, 3)."""
    tree = cKDTree(target)
    rot = np.eye(3)
    trans = np.zeros(3)
    rank = 0
    converged = False
    it = 0
    for it in range(1, max_iterations + 1):
        moved = source @ rot.T + trans
        dist, idx = tree.query(moved)
        keep = dist <= max_distance
        if keep.mean() < min_overlap:
            raise AlignmentError(
                f"ICP: only {keep.mean():.0%} of the {len(source)} source points lie within "
                f"{max_distance:g} of the target (need {min_overlap:.0%}): the clouds do not "
                f"overlap (source box {moved.min(axis=0).round(3).tolist()} .. "
                f"{moved.max(axis=0).round(3).tolist()}, target box "
                f"{target.min(axis=0).round(3).tolist()} .. {target.max(axis=0).round(3).tolist()})")
        p, q, n = moved[keep], target[idx[keep]], target_normals[idx[keep]]
        centre = p.mean(axis=0)  # rotate about the centroid: better conditioned
        arm = float(np.sqrt(np.mean(np.sum((p - centre) ** 2, axis=1)))) or 1.0
        a = np.c_[np.cross(p - centre, n) / arm, n]  # columns of one scale
        b = -np.sum((p - q) * n, axis=1)
        x, _, rank, _ = lstsq(a, b, lapack_driver="gelsd", cond=rcond)
        x[:3] /= arm
        inc = Rotation.from_rotvec(x[:3]).as_matrix()
        # rotation about the centroid then translation: p -> inc (p - c) + c + t
        step_t = centre - inc @ centre + x[3:]
        rot, trans = inc @ rot, inc @ trans + step_t
        motion = np.abs(np.cross(x[:3], p - centre)).max() + np.abs(x[3:]).max()
        if motion < tolerance:
            converged = True
            break
    moved = source @ rot.T + trans
    dist, idx = tree.query(moved)
    keep = dist <= max_distance
    plane = np.abs(np.sum((moved[keep] - target[idx[keep]]) * target_normals[idx[keep]], axis=1))
    return IcpResult(rot, trans, float(plane.mean()), float(dist[keep].mean()),
                     float(keep.mean()), it, converged, int(rank))
