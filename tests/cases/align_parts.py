"""Generated thin-walled parts with known errors, for tests, the benchmark and the figure.

:func:`make_ring`: a cylindrical shell (axis along z). Design: outer radius ``radius``, wall
``thickness``, axis at ``nominal`` (x, y) -- where G54 puts it. Actual part: the inner surface
(which finishing does not touch) has its axis moved by ``inner_shift`` and radius
``radius - thickness + thickness_error``; the cast outer surface has its axis moved by
``outer_shift``, radius ``radius + stock`` and a 3-lobed form error ``lobes``. Probes at
``n_angles x n_heights`` evenly spaced points of the outer surface report the point (noise
``probe_noise``) and the wall thickness perpendicular to the outer surface (noise
``thickness_noise``). The true work-offset shift is ``-inner_shift``.

:func:`make_wall`: a flat wall facing +x (normal along x), inner surface rotated about z by
``angle_deg`` and moved by ``inner_shift``: tests rotation recovery and the
``centre="registration"`` shift of open shapes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from milling_twin.orchestrator.align.spatial import ProbeData

__all__ = ["Part", "make_ring", "make_wall"]


@dataclass(frozen=True)
class Part:
    """Probes, design cloud S3 and the true values: ``shift`` (dx, dy) the compensation must
    find, ``inner_axis`` (ring) and ``angle_deg`` (wall)."""

    probes: ProbeData
    design: np.ndarray
    shift: np.ndarray
    design_thickness: float
    truth: dict[str, float]


def make_ring(inner_shift: tuple[float, float] = (0.5, 0.0),
              outer_shift: tuple[float, float] = (0.1, -0.05), radius: float = 50.0,
              thickness: float = 2.0, thickness_error: float = 0.0, stock: float = 0.4,
              lobes: float = 0.05, height: float = 30.0,
              nominal: tuple[float, float, float] = (200.0, 100.0, -40.0),
              n_angles: int = 24, n_heights: int = 5, probe_noise: float = 0.002,
              thickness_noise: float = 0.005, design_points: tuple[int, int] = (720, 16),
              seed: int = 0) -> Part:
    rng = np.random.default_rng(seed)
    c_nom = np.asarray(nominal[:2], dtype=np.float64)
    z0 = float(nominal[2])
    c_in = c_nom + np.asarray(inner_shift)
    c_out = c_nom + np.asarray(outer_shift)
    r_in = radius - thickness + thickness_error
    phi = np.linspace(0, 2 * np.pi, n_angles, endpoint=False) + 0.1
    zs = np.linspace(z0 + 2.0, z0 + height - 2.0, n_heights)
    pp, zz = np.meshgrid(phi, zs, indexing="ij")
    pp, zz = pp.ravel(), zz.ravel()
    r = radius + stock + lobes * np.cos(3 * pp)
    dr = -3 * lobes * np.sin(3 * pp)
    d = np.c_[np.cos(pp), np.sin(pp)]
    perp = np.c_[-np.sin(pp), np.cos(pp)]
    outer = c_out + r[:, None] * d
    normal = r[:, None] * d - dr[:, None] * perp
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    # thickness along -normal to the inner circle: |outer - s n - c_in| = r_in, smallest s > 0
    w = outer - c_in
    b = np.sum(w * normal, axis=1)
    s = b - np.sqrt(b * b - (np.sum(w * w, axis=1) - r_in ** 2))
    points = np.c_[outer, zz] + rng.normal(0, probe_noise, (pp.size, 3))
    measured = s + rng.normal(0, thickness_noise, pp.size)
    na, nz = design_points
    ta, tz = np.meshgrid(np.linspace(0, 2 * np.pi, na, endpoint=False), np.linspace(
        z0 + 2.0, z0 + height - 2.0, nz), indexing="ij")
    design = np.c_[c_nom[0] + radius * np.cos(ta.ravel()), c_nom[1] + radius * np.sin(ta.ravel()),
                   tz.ravel()]
    return Part(ProbeData(points, measured, "generated ring"), design, -np.asarray(inner_shift),
                thickness, {"inner_x": float(c_in[0]), "inner_y": float(c_in[1]),
                            "inner_radius": r_in})


def make_wall(inner_shift: float = 0.5, angle_deg: float = 0.2, thickness: float = 3.0,
              stock: float = 0.5, size: tuple[float, float] = (80.0, 30.0),
              nominal_x: float = 150.0, n_probes: tuple[int, int] = (9, 4),
              probe_noise: float = 0.002, thickness_noise: float = 0.005,
              design_points: tuple[int, int] = (161, 31), seed: int = 0) -> Part:
    """Wall over y in [0, size[0]], z in [0, size[1]]; design outer face x = nominal_x; actual
    inner face x = nominal_x - thickness + inner_shift + tan(angle) * (y - y_mid)."""
    rng = np.random.default_rng(seed)
    ym = size[0] / 2
    slope = np.tan(np.radians(angle_deg))
    inner = lambda y: nominal_x - thickness + inner_shift + slope * (y - ym)  # noqa: E731
    ys, zs = np.meshgrid(np.linspace(0, size[0], n_probes[0]), np.linspace(0, size[1], n_probes[1]),
                         indexing="ij")
    ys, zs = ys.ravel(), zs.ravel()
    outer_x = nominal_x + stock + 0.1 * np.sin(ys / 15.0)
    # perpendicular thickness ~ horizontal distance * cos(small angles)
    outer_slope = 0.1 / 15.0 * np.cos(ys / 15.0)
    measured = ((outer_x - inner(ys)) / np.sqrt(1 + outer_slope ** 2)
                * np.cos(np.arctan(slope) - np.arctan(outer_slope)))
    points = np.c_[outer_x, ys, zs] + rng.normal(0, probe_noise, (ys.size, 3))
    measured = measured + rng.normal(0, thickness_noise, ys.size)
    dy, dz = np.meshgrid(np.linspace(0, size[0], design_points[0]),
                         np.linspace(0, size[1], design_points[1]), indexing="ij")
    design = np.c_[np.full(dy.size, nominal_x), dy.ravel(), dz.ravel()]
    return Part(ProbeData(points, measured, "generated wall"), design,
                np.array([-inner_shift, 0.0]), thickness, {"angle_deg": angle_deg})
