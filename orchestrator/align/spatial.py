"""Wall-thickness compensation by work-offset shift (the thin-wall patent's method).

Inputs: probe points ``P_i`` of the part's outer surface in machine coordinates with the wall
thickness ``t_i`` measured there (ultrasonic gauge in the spindle), the design wall thickness
``T``, and the design target surface S3 as a point cloud (machine coordinates, the part placed
at the current work offset G54; assumed sampled evenly over its area).

1. Shepard interpolation of the probes gives the outer surface S1 (and the thickness field on
   its grid); S1 moved inward along its normals by the measured thickness is the actual inner
   surface S4; S4 moved outward by ``T`` is the actual target surface S2 (where the outer
   surface must be for the design thickness).
2. ICP registers S3 (source) to S2 (target): rotation R, translation T; F = mean distance of
   the matched S3 points to S2 must not exceed the threshold ``k``.
3. Remaining stock at each S3 point (transformed): its distance to S1 along S1's normal
   (positive: material left to remove; negative: the finished surface would lie outside the
   part).
4. Work-offset shift (dx, dy) = centre of S3 - centre of S4 in XY (area-weighted centroids;
   ``centre="registration"`` uses ``c3 - (R c3 + T)`` instead, which also holds for open
   shapes such as a flat wall, where S3 and S4 centres differ by the thickness). The finishing
   program written for the design must run shifted by -(dx, dy): new work offset
   ``G5x = G54 - (dx, dy)``, set by ``G10 L2 P<n> X.. Y.. Z..`` and called by ``G55``..``G59``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from milling_twin.orchestrator.input_files import InputFileError, open_input
from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.align.icp import IcpResult, icp
from milling_twin.orchestrator.align.surface import GridSurface, interpolate_surface, offset_surface

__all__ = ["Compensation", "ProbeData", "compensate_wall", "load_cloud_csv", "load_probe_csv",
           "work_offset_gcode"]

MIN_PROBES = 6
_REGISTERS = {2: "G55", 3: "G56", 4: "G57", 5: "G58", 6: "G59"}


@dataclass(frozen=True)
class ProbeData:
    """``points`` (k, 3) machine coordinates of the outer surface, ``thickness`` (k,) measured
    there (same unit, > 0); ``source`` names the input in error messages."""

    points: np.ndarray
    thickness: np.ndarray
    source: str = "probes"

    def __post_init__(self) -> None:
        pts = _checked_points(self.points, self.source, "probe points", "to interpolate a surface")
        th = np.asarray(self.thickness, dtype=np.float64)
        if th.shape != (pts.shape[0],):
            raise AlignmentError(f"{self.source}: {th.shape} thickness values for "
                                 f"{pts.shape[0]} points")
        for row, value in enumerate(th):
            if not math.isfinite(value) or value <= 0:
                raise AlignmentError(f"{self.source}: row {row}: thickness must be a finite "
                                     f"number > 0, got {float(value)!r}")
        object.__setattr__(self, "points", pts)
        object.__setattr__(self, "thickness", th)


@dataclass(frozen=True)
class Compensation:
    """Result of :func:`compensate_wall` (unit of the inputs, machine coordinates)."""

    s1: GridSurface
    s4: GridSurface
    s2: GridSurface
    s3: np.ndarray
    s3_registered: np.ndarray
    registration: IcpResult
    threshold: float
    stock: np.ndarray
    centre_s3: np.ndarray
    centre_s4: np.ndarray
    shift: np.ndarray  # (dx, dy)
    rotation_deg: float
    info: dict[str, float] = field(default_factory=dict)

    @property
    def accepted(self) -> bool:
        return self.registration.mean_distance <= self.threshold


def _checked_points(points: np.ndarray, source: str, what: str, purpose: str) -> np.ndarray:
    """``points`` as a finite (k, 3) float array of at least MIN_PROBES rows, else an AlignmentError
    naming ``source`` and the first bad row."""
    c = np.asarray(points, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3:
        raise AlignmentError(f"{source}: {what} must be (k, 3), got {c.shape}")
    if c.shape[0] < MIN_PROBES:
        raise AlignmentError(f"{source}: {c.shape[0]} {what}; at least {MIN_PROBES} are needed {purpose}")
    bad = ~np.isfinite(c)
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise AlignmentError(f"{source}: row {row}: {'xyz'[col]} is not a finite number "
                             f"({float(c[row, col])!r})")
    return c


def _check_cloud(cloud: np.ndarray, source: str) -> np.ndarray:
    return _checked_points(cloud, source, "design points", "for registration")


def _positive(name: str, value: float) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(
            value) or value <= 0:
        raise AlignmentError(f"{name} must be a finite number > 0, got {float(value)!r}")
    return float(value)


def compensate_wall(probes: ProbeData, design: np.ndarray, design_thickness: float,
                    threshold: float, geometry: str = "cylinder", outward: str = "x",
                    resolution: tuple[int, int] = (360, 24), centre: str = "centroid",
                    max_distance: float | None = None, neighbours: int = 8,
                    power: float = 2.0, design_source: str = "design") -> Compensation:
    """Steps 1-4 of the module text. ``threshold`` (k) bounds the ICP mean distance F;
    ``max_distance``: ICP pairing distance (default: 10 x design thickness)."""
    design_thickness = _positive("design_thickness", design_thickness)
    threshold = _positive("threshold", threshold)
    s3 = _check_cloud(design, design_source)
    if centre not in ("centroid", "registration"):
        raise AlignmentError(f"centre must be 'centroid' or 'registration', got {centre!r}")
    if max_distance is None:
        max_distance = 10.0 * design_thickness
    s1, thickness = interpolate_surface(probes.points, probes.thickness, geometry, resolution,
                                        outward=outward, power=power, neighbours=neighbours)
    s4 = offset_surface(s1, -thickness)
    s2 = offset_surface(s4, design_thickness)
    reg = icp(s3, s2.flat_points, s2.flat_normals, max_distance)
    moved = reg.apply(s3)
    # stock: distance of each registered design point to S1 along S1's normal
    from scipy.spatial import cKDTree

    _, idx = cKDTree(s1.flat_points).query(moved)
    stock = np.sum((s1.flat_points[idx] - moved) * s1.flat_normals[idx], axis=1)
    c3 = s3.mean(axis=0)
    c4 = s4.centre()
    if centre == "centroid":
        shift = (c3 - c4)[:2]
    else:
        shift = (c3 - reg.apply(c3[None])[0])[:2]
    angle = float(np.degrees(np.arccos(np.clip((np.trace(reg.rotation) - 1) / 2, -1, 1))))
    info = {"stock_min": float(stock.min()), "stock_mean": float(stock.mean()),
            "stock_max": float(stock.max()), "undercut_points": float((stock < 0).sum())}
    return Compensation(s1, s4, s2, s3, moved, reg, threshold, stock, c3, c4, shift, angle, info)


def work_offset_gcode(shift: np.ndarray, g54: tuple[float, float, float],
                      register: int = 2, decimals: int = 4) -> list[str]:
    """G-code applying ``shift`` = (dx, dy): the new offset ``G54 - (dx, dy)`` (Z as G54) into
    register ``P<register>`` (2..6 = G55..G59), and the call to put at the start of the
    finishing program."""
    if register not in _REGISTERS:
        raise AlignmentError(f"register must be 2..6 (G55..G59), got {register!r}")
    g = [float(v) for v in g54]
    if len(g) != 3 or not all(math.isfinite(v) for v in g):
        raise AlignmentError(f"G54 must be three finite numbers (x, y, z), got {g54!r}")
    dx, dy = float(shift[0]), float(shift[1])
    x, y, z = g[0] - dx, g[1] - dy, g[2]
    fmt = f"{{:.{decimals}f}}"
    return [f"G10 L2 P{register} X{fmt.format(x)} Y{fmt.format(y)} Z{fmt.format(z)}",
            _REGISTERS[register]]


def _read_csv(path: Path, columns: list[str]) -> pd.DataFrame:
    if not path.exists():
        raise AlignmentError(f"{path}: file not found")
    try:
        with open_input(path, "CSV file") as fh:  # a regular file only (orchestrator/input_files.py)
            frame = pd.read_csv(fh)
    except InputFileError as exc:
        raise AlignmentError(exc.detail) from None
    except (pd.errors.ParserError, pd.errors.EmptyDataError, UnicodeDecodeError) as exc:
        raise AlignmentError(f"{path}: not a readable CSV file: {exc}") from None
    if len(frame.columns) < 2:  # no comma in line 1: not a table of named columns, and not quoted
        raise AlignmentError(f"{path}: not a CSV file (line 1 is not a header of comma-separated column names; "
                             f"looked for the columns {', '.join(columns)})")
    missing = [c for c in columns if c not in frame.columns]
    if missing:
        raise AlignmentError(f"{path}: no column {missing[0]!r}; columns: {list(frame.columns)}")
    out = frame[columns].apply(pd.to_numeric, errors="coerce")
    bad = out.isna().to_numpy()
    if bad.any():
        row, col = np.argwhere(bad)[0]
        raise AlignmentError(f"{path}: line {row + 2}, column {columns[col]!r}: "
                             f"{frame[columns[col]].iloc[row]!r} is not a number")
    return out


def load_probe_csv(path: str | Path, thickness_column: str = "thickness") -> ProbeData:
    """Probe points: columns x, y, z and ``thickness_column``; errors name file, line, column."""
    path = Path(path)
    frame = _read_csv(path, ["x", "y", "z", thickness_column])
    th = frame[thickness_column].to_numpy()
    for row, value in enumerate(th):
        if value <= 0:
            raise AlignmentError(f"{path}: line {row + 2}, column {thickness_column!r}: "
                                 f"thickness must be > 0, got {float(value)!r}")
    return ProbeData(frame[["x", "y", "z"]].to_numpy(), th, str(path))


def load_cloud_csv(path: str | Path) -> np.ndarray:
    """Design cloud: columns x, y, z."""
    path = Path(path)
    return _check_cloud(_read_csv(path, ["x", "y", "z"]).to_numpy(), str(path))
