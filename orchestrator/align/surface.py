"""Surfaces on a parameter grid: S1 interpolated from probe points, offsets along normals,
area-weighted centres.

Two parametrisations of the probed outer surface (both graphs over a 2-D parameter domain):

* ``cylinder``: axis parallel to z through ``centre`` (x, y); parameters (angle, z), value the
  radius. Neighbours for Shepard are searched on the nominal cylinder (x = R cos a,
  y = R sin a, z), so the angle wraps around.
* ``plane``: a wall facing ``outward`` (a unit vector along x, y or z); parameters the two
  other coordinates, value the coordinate along the outward axis.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.linalg import lstsq

from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.align.shepard import shepard

__all__ = ["GridSurface", "fit_circle", "interpolate_surface", "offset_surface"]


@dataclass(frozen=True)
class GridSurface:
    """``points`` (nu, nv, 3) on a parameter grid, ``normals`` (nu, nv, 3) unit, outward;
    ``closed_u``: the first parameter wraps around (cylinder angle)."""

    points: np.ndarray
    normals: np.ndarray
    closed_u: bool = False

    @property
    def flat_points(self) -> np.ndarray:
        return self.points.reshape(-1, 3)

    @property
    def flat_normals(self) -> np.ndarray:
        return self.normals.reshape(-1, 3)

    def area_weights(self) -> np.ndarray:
        """Area element of each grid point (nu * nv,), from the grid tangents."""
        du, dv = _tangents(self.points, self.closed_u)
        return np.linalg.norm(np.cross(du, dv), axis=-1).reshape(-1)

    def centre(self) -> np.ndarray:
        """Area-weighted centroid: the centre of a cylinder shell is on its axis whatever the
        grid's own parametrisation centre."""
        w = self.area_weights()
        return (self.flat_points * w[:, None]).sum(axis=0) / w.sum()


def _tangents(points: np.ndarray, closed_u: bool) -> tuple[np.ndarray, np.ndarray]:
    if closed_u:
        du = 0.5 * (np.roll(points, -1, axis=0) - np.roll(points, 1, axis=0))
    else:
        du = np.gradient(points, axis=0)
    dv = np.gradient(points, axis=1)
    return du, dv


def grid_normals(points: np.ndarray, closed_u: bool, outward: np.ndarray) -> np.ndarray:
    """Unit normals of a grid surface, oriented so that they point along ``outward``
    ((nu, nv, 3) or (3,): the rough outward direction at each point)."""
    du, dv = _tangents(points, closed_u)
    n = np.cross(du, dv)
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    if np.any(length <= 0):
        raise AlignmentError("degenerate surface grid: zero-area element (repeated points)")
    n = n / length
    flip = np.sum(n * outward, axis=-1, keepdims=True) < 0
    return np.where(flip, -n, n)


def fit_circle(xy: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares (Kasa) circle through points (k, 2): centre, radius."""
    a = np.c_[2 * xy[:, 0], 2 * xy[:, 1], np.ones(len(xy))]
    b = (xy ** 2).sum(axis=1)
    sol = lstsq(a, b)[0]
    centre = sol[:2]
    return centre, float(np.sqrt(max(sol[2] + centre @ centre, 0.0)))


_AXES = {"x": 0, "y": 1, "z": 2}


def interpolate_surface(points: np.ndarray, values: np.ndarray, geometry: str,
                        resolution: tuple[int, int], centre: np.ndarray | None = None,
                        outward: str = "x", power: float = 2.0,
                        neighbours: int = 8) -> tuple[GridSurface, np.ndarray]:
    """Shepard-interpolate probe ``points`` (k, 3) into a grid surface over the probes'
    parameter range, and ``values`` (k, ...) onto the same grid. Returns the surface and the
    values (nu, nv, ...)."""
    nu, nv = resolution
    if geometry == "cylinder":
        if centre is None:
            centre, _ = fit_circle(points[:, :2])
        rel = points[:, :2] - centre
        radius = np.hypot(rel[:, 0], rel[:, 1])
        r0 = float(np.median(radius))
        ang = np.arctan2(rel[:, 1], rel[:, 0])
        embed = np.c_[r0 * np.cos(ang), r0 * np.sin(ang), points[:, 2]]
        u = np.linspace(-np.pi, np.pi, nu, endpoint=False)
        v = np.linspace(points[:, 2].min(), points[:, 2].max(), nv)
        uu, vv = np.meshgrid(u, v, indexing="ij")
        query = np.c_[r0 * np.cos(uu.ravel()), r0 * np.sin(uu.ravel()), vv.ravel()]
        both = shepard(embed, np.c_[radius, values.reshape(len(points), -1)], query, power,
                       neighbours)
        r = both[:, 0].reshape(nu, nv)
        grid = np.stack([centre[0] + r * np.cos(uu), centre[1] + r * np.sin(uu), vv], axis=-1)
        radial = np.stack([np.cos(uu), np.sin(uu), np.zeros_like(uu)], axis=-1)
        surface = GridSurface(grid, grid_normals(grid, True, radial), closed_u=True)
        return surface, both[:, 1:].reshape((nu, nv) + values.shape[1:])
    if geometry == "plane":
        if outward not in _AXES:
            raise AlignmentError(f"plane geometry: outward must be one of x, y, z, got "
                                 f"{outward!r}")
        k = _AXES[outward]
        p, q = [a for a in range(3) if a != k]
        u = np.linspace(points[:, p].min(), points[:, p].max(), nu)
        v = np.linspace(points[:, q].min(), points[:, q].max(), nv)
        uu, vv = np.meshgrid(u, v, indexing="ij")
        query = np.c_[uu.ravel(), vv.ravel()]
        both = shepard(points[:, [p, q]], np.c_[points[:, k], values.reshape(len(points), -1)],
                       query, power, neighbours)
        grid = np.empty((nu, nv, 3))
        grid[..., p], grid[..., q], grid[..., k] = uu, vv, both[:, 0].reshape(nu, nv)
        direction = np.zeros(3)
        direction[k] = 1.0
        surface = GridSurface(grid, grid_normals(grid, False, direction))
        return surface, both[:, 1:].reshape((nu, nv) + values.shape[1:])
    raise AlignmentError(f"unknown geometry {geometry!r}: expected 'cylinder' or 'plane'")


def offset_surface(surface: GridSurface, distance: np.ndarray | float) -> GridSurface:
    """The surface moved by ``distance`` (scalar or (nu, nv)) along its outward normals
    (negative: inward); normals recomputed on the new grid."""
    d = np.broadcast_to(np.asarray(distance, dtype=np.float64), surface.points.shape[:2])
    moved = surface.points + d[..., None] * surface.normals
    return GridSurface(moved, grid_normals(moved, surface.closed_u, surface.normals),
                       surface.closed_u)
