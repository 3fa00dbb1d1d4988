"""The machined surface of a whole-part run: the final Z-map, its volume and STL, the check of the removed
volume per block, and the surface location error of the walls.

- **Z-map** (``models.workpiece.read_zmap`` of the Workpiece's ``zmap_file``): cell-centre heights [m] over an
  ``nx x ny`` grid of ``dx x dy`` cells that fits the stock block exactly. Its volume is
  ``sum(height - stock bottom) * dx * dy``; stock volume minus it is the removed volume, the same cells the
  Workpiece's ``removed_volume`` output sums (they agree to rounding).
- **STL** (binary, **mm**): a closed solid: the top surface triangulated (two triangles per quad) through the
  cell-centre heights, extended half a cell to the stock's edges with the edge cells' heights; four vertical
  side walls down to the stock bottom; the bottom (two triangles). Its volume equals the Z-map volume up to
  ``dx dy / 12 * (h00 + h11 - h10 - h01)`` of the four corner cells (the quads' diagonal; 0 when the corners
  are uncut).
- **Analytic volume** of a block that is a straight horizontal cut at constant depth: width (median radial
  depth) x depth (median axial depth) x the tool's travel over the steady part of the cut (the in-cut samples
  from one tool radius after the first, where the full width is engaged, to the last, or to two radii before
  it when the tool leaves the material within the block), against the removed volume over the same samples.
- **Surface location error** (SLE): the tool-tip displacement normal to the feed direction at the moments a
  flute's tip passes the immersion angle that generates the finished wall: pi (the right-hand wall, down
  milling: exit angle pi), 0 (the left-hand wall, up milling: entry angle 0), both for a slot. Positive: the
  tool is deflected away from the wall into the cut (material left on the wall). The flute angle is
  ``force.spindle_angle`` + j 2pi/n_flutes + the feed direction; the displacement is interpolated linearly to
  the crossing time between samples.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from milling_twin.orchestrator.part.blocks import Signals, Spans
from milling_twin.orchestrator.part.model import FORCE, INTERPOLATOR, WORKPIECE

WALL_ANGLE_TOLERANCE = 0.02   # rad: entry <= this is a left wall (up milling), exit >= pi - this a right wall
MIN_STEADY_CELLS = 10         # the steady part of a straight cut must be this many cells long

__all__ = ["ZMapGrid", "analytic_volumes", "load_zmap", "stl_mesh", "surface_location_errors", "write_stl"]


@dataclass(frozen=True)
class ZMapGrid:
    """Cell-centre coordinates (ascending, m) and heights [ny, nx] (m)."""
    x: np.ndarray
    y: np.ndarray
    heights: np.ndarray

    @property
    def dx(self) -> float:
        return float(self.x[1] - self.x[0]) if self.x.size > 1 else math.nan

    @property
    def dy(self) -> float:
        return float(self.y[1] - self.y[0]) if self.y.size > 1 else math.nan

    def volume(self, bottom: float) -> float:
        """Material above ``bottom`` (m3): sum of (height - bottom) times the cell area."""
        above = np.maximum(np.nan_to_num(self.heights, nan=bottom) - bottom, 0.0)
        return float(above.sum() * self.dx * self.dy)


def load_zmap(path: Path, offset: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> ZMapGrid:
    """The Workpiece's final Z-map file (read by ``models.workpiece.read_zmap``), y ascending, ``offset``
    subtracted from its coordinates and heights (the part's program zero: the Workpiece holds the stock in
    machine coordinates, the part gives it in the program's)."""
    from milling_twin.models.workpiece import read_zmap

    x, y, heights = read_zmap(path)
    x = np.asarray(x, float) - offset[0]
    y = np.asarray(y, float) - offset[1]
    heights = np.asarray(heights, float) - offset[2]
    if x.size > 1 and x[1] < x[0]:
        x, heights = x[::-1], heights[:, ::-1]
    if y.size > 1 and y[1] < y[0]:
        y, heights = y[::-1], heights[::-1, :]
    return ZMapGrid(x, y, heights)


def _wall(chain: np.ndarray, bottom: float) -> np.ndarray:
    """Triangles of a vertical wall under ``chain`` (points along the top edge, left to right as seen from
    outside) down to ``bottom``: fans from the two bottom corners, outward normals."""
    m = len(chain)
    b0 = np.array([chain[0, 0], chain[0, 1], bottom])
    b1 = np.array([chain[-1, 0], chain[-1, 1], bottom])
    k = (m - 1) // 2
    left = np.stack([np.broadcast_to(b0, (k, 3)), chain[1:k + 1], chain[:k]], axis=1)
    middle = np.stack([b0, b1, chain[k]])[None]
    right = np.stack([np.broadcast_to(b1, (m - 1 - k, 3)), chain[k + 1:], chain[k:m - 1]], axis=1)
    return np.concatenate([left, middle, right])


def stl_mesh(grid: ZMapGrid, bottom: float, *, scale: float = 1000.0):  # -> stl.mesh.Mesh
    """The closed solid of the Z-map above ``bottom`` (module text), coordinates times ``scale`` (m -> mm)."""
    from stl import mesh as stl_module

    dx, dy = grid.dx, grid.dy
    xs = np.r_[grid.x[0] - 0.5 * dx, grid.x, grid.x[-1] + 0.5 * dx] * scale
    ys = np.r_[grid.y[0] - 0.5 * dy, grid.y, grid.y[-1] + 0.5 * dy] * scale
    h = np.pad(np.nan_to_num(grid.heights, nan=bottom), 1, mode="edge") * scale
    z0 = bottom * scale
    gx, gy = np.meshgrid(xs, ys)
    points = np.stack([gx, gy, h], axis=-1)                     # [NY, NX, 3]
    a, b = points[:-1, :-1], points[:-1, 1:]
    c, d = points[1:, 1:], points[1:, :-1]
    top = np.concatenate([np.stack([a, b, c], axis=2).reshape(-1, 3, 3),
                          np.stack([a, c, d], axis=2).reshape(-1, 3, 3)])
    walls = [_wall(points[0, :], z0),              # y min, seen from -y: x increasing
             _wall(points[:, -1], z0),             # x max, seen from +x: y increasing
             _wall(points[-1, ::-1], z0),          # y max, seen from +y: x decreasing
             _wall(points[::-1, 0], z0)]           # x min, seen from -x: y decreasing
    corners = np.array([[xs[0], ys[0], z0], [xs[-1], ys[0], z0], [xs[-1], ys[-1], z0], [xs[0], ys[-1], z0]])
    floor = np.stack([corners[[0, 2, 1]], corners[[0, 3, 2]]])
    triangles = np.concatenate([top, *walls, floor])
    solid = stl_module.Mesh(np.zeros(len(triangles), dtype=stl_module.Mesh.dtype))
    solid.vectors[:] = triangles
    solid.update_normals()
    return solid


def write_stl(grid: ZMapGrid, bottom: float, path: Path) -> int:
    """Write the solid as binary STL in mm; returns the number of triangles."""
    from stl import Mode

    solid = stl_mesh(grid, bottom)
    solid.save(str(path), mode=Mode.BINARY)
    return len(solid.vectors)


def _spindle_angle(signals: Signals) -> np.ndarray:
    """Unwrapped angle of flute 0 (rad): the force model's, else the commanded spindle speed summed as the force
    model advances its angle: each step by the speed at its end (the Interpolator steps first) times its length."""
    if signals.has(f"{FORCE}.spindle_angle"):
        return np.unwrap(np.nan_to_num(signals[f"{FORCE}.spindle_angle"]))
    omega = np.nan_to_num(signals[f"{INTERPOLATOR}.spindle_speed"])
    return np.r_[0.0, np.cumsum(omega[1:] * np.diff(signals.time))]


def feed_direction(signals: Signals, interpolation_period: float) -> np.ndarray:
    """Feed direction angle from +x (rad) per sample: the Interpolator's feed velocity, else the direction of
    travel over +-2 interpolation periods (its positions change once per period)."""
    if signals.has(f"{INTERPOLATOR}.feed_velocity_x") and signals.has(f"{INTERPOLATOR}.feed_velocity_y"):
        return np.arctan2(signals[f"{INTERPOLATOR}.feed_velocity_y"], signals[f"{INTERPOLATOR}.feed_velocity_x"])
    x, y = signals[f"{INTERPOLATOR}.x"], signals[f"{INTERPOLATOR}.y"]
    n = signals.n
    if n < 2:
        return np.zeros(n)
    dt = float(np.median(np.diff(signals.time)))
    lag = max(1, int(round(2.0 * interpolation_period / dt))) if dt > 0 else 1
    i = np.arange(n)
    ahead, behind = np.minimum(i + lag, n - 1), np.maximum(i - lag, 0)
    return np.arctan2(y[ahead] - y[behind], x[ahead] - x[behind])


def surface_location_errors(signals: Signals, spans: Spans, n_flutes: int | np.ndarray, interpolation_period: float
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per block: mean SLE, largest |SLE| (m) and the number of wall-generating flute passes (module text).
    ``n_flutes``: the tool's flutes, or each block's (a part with several tools); a block with none has NaN."""
    n_blocks = len(spans)
    nan = np.full(n_blocks, np.nan)
    flutes = np.broadcast_to(np.asarray(n_flutes, dtype=np.int64), (n_blocks,))
    dx, dy = signals.deflection()
    if n_blocks == 0 or not (flutes >= 1).any() or np.isnan(dx).all() or signals.n < 2:
        return nan, nan.copy(), np.zeros(n_blocks, dtype=np.int64)
    in_cut = signals.in_cut()
    entry = np.nan_to_num(signals[f"{WORKPIECE}.entry_angle"], nan=-1.0)
    exit_ = np.nan_to_num(signals[f"{WORKPIECE}.exit_angle"], nan=-1.0)
    theta = _spindle_angle(signals)
    feed = np.unwrap(feed_direction(signals, interpolation_period))
    normal_x, normal_y = -np.sin(feed), np.cos(feed)          # +y of the feed frame (left of the feed)
    normal = np.nan_to_num(dx) * normal_x + np.nan_to_num(dy) * normal_y
    sample_flutes = spans.per_sample(flutes, signals.n, 0.0)
    has_flutes = sample_flutes >= 1
    pitch = 2.0 * math.pi / np.where(has_flutes, sample_flutes, 1.0)
    values, indices = [], []
    # a pass counts between two samples of one tool's cut (a tool change between them changes the pitch)
    both = in_cut[:-1] & in_cut[1:] & has_flutes[:-1] & (sample_flutes[1:] == sample_flutes[:-1])
    for wall, side, sign in ((math.pi, exit_ >= math.pi - WALL_ANGLE_TOLERANCE, 1.0),
                             (0.0, (entry >= 0.0) & (entry <= WALL_ANGLE_TOLERANCE), -1.0)):
        g = theta + feed - wall
        k = np.floor(g / pitch)
        crossing = np.flatnonzero(both & side[:-1] & side[1:] & (k[1:] > k[:-1]))
        if crossing.size == 0:
            continue
        g0, g1 = g[crossing], g[crossing + 1]
        s = np.clip((k[crossing + 1] * pitch[crossing] - g0) / (g1 - g0), 0.0, 1.0)
        values.append(sign * (normal[crossing] + s * (normal[crossing + 1] - normal[crossing])))
        indices.append(crossing)
    if not values:
        return nan, nan.copy(), np.zeros(n_blocks, dtype=np.int64)
    value, index = np.concatenate(values), np.concatenate(indices)
    block = np.searchsorted(spans.starts, index, side="right") - 1
    inside = (block >= 0) & (index < spans.stops[np.maximum(block, 0)])
    value, block = value[inside], block[inside]
    count = np.bincount(block, minlength=n_blocks)
    total = np.bincount(block, weights=value, minlength=n_blocks)
    largest = np.full(n_blocks, -np.inf)
    np.maximum.at(largest, block, np.abs(value))
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(count > 0, total / count, np.nan)
    return mean, np.where(count > 0, largest, np.nan), count


def _constant(values: np.ndarray, median: float, resolution: float) -> bool:
    """The 5..95 % range of ``values`` within half a cell or 1 % of their median."""
    spread = float(np.percentile(values, 95) - np.percentile(values, 5))
    return spread <= max(0.5 * resolution, 0.01 * median)


def analytic_volumes(signals: Signals, spans: Spans, tool_diameter: float | np.ndarray, resolution: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Per block: the analytic volume of the steady part of a straight cut at constant depth and the volume the
    Workpiece removed over the same samples (m3; NaN where the block is not such a cut; module text).
    ``tool_diameter``: the tool's, or each block's (a part with several tools)."""
    n_blocks = len(spans)
    radii = 0.5 * np.broadcast_to(np.asarray(tool_diameter, dtype=float), (n_blocks,))
    analytic, removed = np.full(n_blocks, np.nan), np.full(n_blocks, np.nan)
    if not signals.has(f"{WORKPIECE}.removed_volume"):
        return analytic, removed
    x, y, z = (signals[f"{INTERPOLATOR}.{a}"] for a in "xyz")
    volume = signals[f"{WORKPIECE}.removed_volume"]
    axial, radial = signals[f"{WORKPIECE}.axial_depth"], signals[f"{WORKPIECE}.radial_depth"]
    in_cut = signals.in_cut()
    step = np.r_[0.0, np.hypot(np.diff(x), np.diff(y))]
    travel = np.cumsum(np.nan_to_num(step))
    for b, (i0, i1, radius) in enumerate(zip(spans.starts, spans.stops, radii)):
        cut = np.flatnonzero(in_cut[i0:i1]) + i0
        if cut.size < 10:
            continue
        first, last = int(cut[0]), int(cut[-1])
        leaves = last < i1 - 1        # the tool leaves the material within the block
        start_s = travel[first] + radius
        end_s = travel[last] - (2.0 * radius if leaves else 0.0)
        if end_s - start_s < MIN_STEADY_CELLS * resolution:
            continue
        window = np.flatnonzero((travel >= start_s) & (travel <= end_s) & in_cut)
        window = window[(window >= first) & (window <= last)]
        if window.size < 2:
            continue
        a, c = int(window[0]), int(window[-1])
        # straight, horizontal, constant depth over the window
        px, py = x[a:c + 1] - x[a], y[a:c + 1] - y[a]
        length = math.hypot(px[-1], py[-1])
        if length <= 0 or np.ptp(z[a:c + 1]) > 0.1 * resolution:
            continue
        off_line = np.abs(px * py[-1] - py * px[-1]) / length
        if off_line.max() > 0.5 * resolution:
            continue
        depths, widths = axial[window], radial[window]
        depth, width = float(np.median(depths)), float(np.median(widths))
        if not (depth > 0 and width > 0 and _constant(depths, depth, resolution)
                and _constant(widths, width, resolution)):
            continue
        analytic[b] = width * depth * (travel[c] - travel[a])
        removed[b] = volume[c] - volume[a]
    return analytic, removed
