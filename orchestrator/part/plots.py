"""Figures of the process report as PNG bytes (matplotlib's Agg through ``Figure``: no pyplot state).

Long signals are drawn as their envelope: the minimum and maximum of each of ``ENVELOPE_BINS`` time bins,
which is what a line through every sample shows at this width, at a fraction of the cost (a 100 s part at
1e-4 s is 1e6 samples).
"""
from __future__ import annotations

import io
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from matplotlib.collections import LineCollection
from matplotlib.colors import Normalize
from matplotlib.figure import Figure
from mpl_toolkits.mplot3d.art3d import Line3DCollection

from milling_twin.models.stability import Lobes

ENVELOPE_BINS = 2000
PATH_POINTS = 20000   # the 3D tool path is drawn through at most this many samples
LOBE_NAMES = 30       # the blocks on the lobe diagram are named when there are at most this many

__all__ = ["Series", "envelope", "lobes_png", "time_series_png", "toolpath_png", "zmap_png"]


@dataclass(frozen=True)
class Series:
    label: str           # axis label with its unit
    values: np.ndarray   # display unit


def _png(fig: Figure) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=90)
    return buffer.getvalue()


def envelope(t: np.ndarray, values: np.ndarray, bins: int = ENVELOPE_BINS) -> tuple[np.ndarray, np.ndarray]:
    """(times, values) of a line through the min and max of each of ``bins`` equal time bins."""
    if t.size <= 2 * bins:
        return t, values
    edges = np.linspace(0, t.size, bins + 1).astype(np.int64)
    v = np.nan_to_num(values, nan=0.0)
    low = np.minimum.reduceat(v, edges[:-1])
    high = np.maximum.reduceat(v, edges[:-1])
    mid = t[(edges[:-1] + edges[1:]) // 2]
    return np.repeat(mid, 2), np.column_stack([low, high]).ravel()


def time_series_png(t: np.ndarray, series: Sequence[Series], boundaries: np.ndarray,
                    labels: Sequence[tuple[float, str]], title: str) -> bytes:
    """One panel per series over time, thin vertical lines at the block starts, ``labels`` (time, text) on top."""
    fig = Figure(figsize=(12, 2.3 * max(len(series), 1) + 0.6), layout="constrained")
    axes = np.atleast_1d(fig.subplots(max(len(series), 1), 1, sharex=True))
    for ax, s in zip(axes, series):
        et, ev = envelope(t, s.values)
        ax.plot(et, ev, linewidth=0.6, color="tab:blue")
        ax.set_ylabel(s.label)
        ax.grid(True, alpha=0.3)
        if boundaries.size:  # one line through all of them, NaN between: thousands of blocks draw at once
            bx = np.repeat(boundaries, 3)
            bx[2::3] = np.nan
            by = np.tile([0.0, 1.0, np.nan], boundaries.size)
            ax.plot(bx, by, transform=ax.get_xaxis_transform(), color="0.6", linewidth=0.4, alpha=0.6)
    for time, text in labels:
        axes[0].annotate(text, (time, 1.0), xycoords=("data", "axes fraction"), xytext=(0, 2),
                         textcoords="offset points", fontsize=7, rotation=90, va="bottom", ha="center")
    axes[-1].set_xlabel("time [s]")
    axes[0].set_title(title, pad=40 if labels else 6)
    return _png(fig)


def toolpath_png(x: np.ndarray, y: np.ndarray, z: np.ndarray, colour: np.ndarray, rapid: np.ndarray,
                 label: str, title: str, box: Sequence[tuple[float, float]] | None = None, cmap: str = "viridis",
                 vmin: float | None = None, vmax: float | None = None) -> bytes:
    """The 3D tool path (mm) coloured by ``colour`` (NaN: grey), rapid moves grey; ``box``: the stock's
    (min, max) in x, y, z (mm), drawn as thin edges and included in the axes' ranges."""
    step = max(1, x.size // PATH_POINTS)
    x, y, z, colour, rapid = x[::step], y[::step], z[::step], colour[::step], rapid[::step]
    fig = Figure(figsize=(9, 7), layout="constrained")
    ax = fig.add_subplot(projection="3d")
    points = np.column_stack([x, y, z])
    segments = np.stack([points[:-1], points[1:]], axis=1)
    c = colour[1:]
    grey = rapid[1:] | ~np.isfinite(c)
    finite = c[np.isfinite(c)]
    norm = Normalize(vmin if vmin is not None else (float(finite.min()) if finite.size else 0.0),
                     vmax if vmax is not None else (float(finite.max()) if finite.size else 1.0))
    if grey.any():
        ax.add_collection3d(Line3DCollection(segments[grey], colors="0.45", linewidths=0.8, linestyles="dashed"))
    coloured = Line3DCollection(segments[~grey], cmap=cmap, norm=norm, linewidths=1.2)
    coloured.set_array(c[~grey])
    if (~grey).any():
        ax.add_collection3d(coloured)
    bounds = [[float(np.nanmin(v)), float(np.nanmax(v))] if v.size else [0.0, 1.0] for v in (x, y, z)]
    if box is not None:
        (x0, x1), (y0, y1), (z0, z1) = box
        corners = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]])
        edges = [np.column_stack([corners, np.full(5, h)]) for h in (z0, z1)]
        edges += [np.array([[cx, cy, z0], [cx, cy, z1]]) for cx, cy in corners[:4]]
        ax.add_collection3d(Line3DCollection(edges, colors="0.55", linewidths=0.5))
        bounds = [[min(b[0], lo), max(b[1], hi)] for b, (lo, hi) in zip(bounds, box)]
    ranges = [max(hi - lo, 1e-6) for lo, hi in bounds]
    for setter, (lo, hi), r in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), bounds, ranges):
        setter(lo - 0.03 * r, hi + 0.03 * r)
    largest = max(ranges)
    ax.set_box_aspect([max(r, 0.2 * largest) for r in ranges])  # true proportions, no axis flatter than 1/5
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    ax.set_zlabel("z [mm]")
    fig.colorbar(coloured, ax=ax, shrink=0.6, label=label)
    ax.set_title(title)
    return _png(fig)


def zmap_png(x_mm: np.ndarray, y_mm: np.ndarray, heights_mm: np.ndarray, title: str) -> bytes:
    """The Z-map's heights as an image (mm), equal axes, colour bar."""
    fig = Figure(figsize=(10, 6.5), layout="constrained")
    ax = fig.subplots()
    dx = x_mm[1] - x_mm[0] if x_mm.size > 1 else 1.0
    dy = y_mm[1] - y_mm[0] if y_mm.size > 1 else 1.0
    image = ax.imshow(heights_mm, origin="lower", cmap="viridis", interpolation="nearest",
                      extent=(x_mm[0] - dx / 2, x_mm[-1] + dx / 2, y_mm[0] - dy / 2, y_mm[-1] + dy / 2))
    ax.set_aspect("equal")
    ax.set_xlabel("x [mm]")
    ax.set_ylabel("y [mm]")
    fig.colorbar(image, ax=ax, label="height [mm]", shrink=0.8)
    ax.set_title(title)
    return _png(fig)


def lobes_png(lobes: Lobes, speeds_rpm: np.ndarray, depths_mm: np.ndarray, indicators: np.ndarray,
              threshold: float, title: str, names: Sequence[str] = ()) -> bytes:
    """Limiting axial depth over spindle speed (mm over rpm) and the cutting blocks coloured by their chatter
    indicator (hollow: no indicator; the highest indicator drawn on top), named by ``names`` when there are at
    most LOBE_NAMES of them."""
    fig = Figure(figsize=(10, 6), layout="constrained")
    ax = fig.subplots()
    finite = np.isfinite(speeds_rpm) & (speeds_rpm > 0)
    if finite.any():
        low, high = 0.5 * speeds_rpm[finite].min(), 1.5 * speeds_rpm[finite].max()
    else:
        low, high = float(np.nanmin(lobes.speed)), float(np.nanmax(lobes.speed[0]))
    depth_mm = lobes.depth * 1e3
    segments = [np.column_stack([lobe, depth_mm]) for lobe in lobes.speed]
    ax.add_collection(LineCollection(segments, colors="tab:blue", linewidths=1.0, label="stability limit"))
    limit = lobes.limit(np.linspace(low, high, 400)) * 1e3
    lowest = float(np.nanmin(limit[np.isfinite(limit)])) if np.isfinite(limit).any() else 1.0
    deepest = float(np.nanmax(depths_mm)) if np.isfinite(depths_mm).any() else 0.0
    top = max(3.0 * lowest, 1.3 * deepest)
    ax.set_xlim(low, high)
    ax.set_ylim(0, top if top > 0 else 1.0)
    known = np.flatnonzero(finite & np.isfinite(indicators))
    known = known[np.argsort(indicators[known], kind="stable")]
    scatter = ax.scatter(speeds_rpm[known], depths_mm[known], c=indicators[known], cmap="coolwarm", vmin=0, vmax=1,
                         edgecolors="black", linewidths=0.5, s=30, zorder=3, label="blocks (max axial depth)")
    if 0 < len(names) <= LOBE_NAMES:  # blocks at the same point share one label
        at: dict[tuple[float, float], list[str]] = {}
        for i in np.flatnonzero(finite):
            at.setdefault((round(float(speeds_rpm[i]), 1), round(float(depths_mm[i]), 4)), []).append(names[i])
        for (speed, depth), group in at.items():
            ax.annotate(", ".join(group), (speed, depth), xytext=(4, 3), textcoords="offset points", fontsize=7)
    unknown = finite & ~np.isfinite(indicators)
    if unknown.any():
        ax.scatter(speeds_rpm[unknown], depths_mm[unknown], facecolors="none", edgecolors="0.4", s=30, zorder=3,
                   label="blocks without an indicator")
    fig.colorbar(scatter, ax=ax, label=f"chatter indicator (chatter above {threshold:g})")
    ax.set_xlabel("spindle speed [rpm]")
    ax.set_ylabel("limiting axial depth [mm]")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper left")
    ax.set_title(title)
    return _png(fig)
