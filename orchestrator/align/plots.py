"""Figures (PNG, matplotlib Agg): temporal alignment before/after, and the spatial compensation."""
from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from milling_twin.orchestrator.align.spatial import Compensation  # noqa: E402
from milling_twin.orchestrator.align.timemap import TimeMap  # noqa: E402
from milling_twin.orchestrator.align.trajectory import Trajectory  # noqa: E402

__all__ = ["plot_spatial", "plot_temporal"]

_COLORS = ("tab:blue", "tab:orange", "tab:green")


def plot_temporal(recorded: Trajectory, simulated: Trajectory, time_map: TimeMap,
                  path: str | Path, title: str = "", truth: np.ndarray | None = None,
                  unit: str = "mm", window: tuple[float, float] | None = None) -> Path:
    """Three panels over recorded time: positions before alignment (simulated on its own
    clock), after (simulated at the mapped times), and the map (with ``truth`` if known) with
    its confidence. ``window`` limits the time axis."""
    path = Path(path)
    t = recorded.time
    fig, ax = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True,
                           gridspec_kw={"height_ratios": [1, 1, 0.8]})
    after = time_map.resample_simulated(simulated.time, simulated.position)
    for a, name in enumerate("xyz"):
        ax[0].plot(t, recorded.position[:, a], color=_COLORS[a], lw=1.2, label=f"{name} recorded")
        ax[0].plot(simulated.time, simulated.position[:, a], color=_COLORS[a], lw=0.9, ls="--",
                   label=f"{name} simulated")
        ax[1].plot(t, recorded.position[:, a], color=_COLORS[a], lw=1.2)
        ax[1].plot(t, after[:, a], color=_COLORS[a], lw=0.9, ls="--")
    ax[0].set_title("before alignment (simulated on its own clock)", fontsize=9)
    ax[1].set_title(f"after alignment ({time_map.method}): simulated at the mapped times",
                    fontsize=9)
    for k in (0, 1):
        ax[k].set_ylabel(f"position ({unit})")
    ax[0].legend(ncol=3, fontsize=7, loc="upper right")
    ax[2].plot(t, time_map.simulated_time, color="k", lw=1.2, label="map")
    if truth is not None:
        ax[2].plot(t, truth, color="tab:red", lw=0.8, ls=":", label="true")
    ax[2].set_ylabel("simulated time (s)")
    ax[2].set_xlabel("recorded time (s)")
    twin = ax[2].twinx()
    twin.fill_between(t, time_map.confidence, color="tab:gray", alpha=0.25, step="mid")
    twin.set_ylim(0, 1.05)
    twin.set_ylabel("confidence")
    ax[2].legend(fontsize=7, loc="upper left")
    if window is not None:
        ax[2].set_xlim(*window)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path


def plot_spatial(comp: Compensation, path: str | Path, title: str = "",
                 exaggerate: float = 40.0, unit: str = "mm") -> Path:
    """Left: mid-height section of the part, deviations from the design surface S3 magnified
    ``exaggerate`` times, with S1 (probed outer), S2 (actual target), S3 (design) and S3
    registered, the centre of S3 (+) and the move of the program, -(dx, dy), as an arrow
    (magnified alike). Right: the surfaces' deviation from S3 along the section."""
    path = Path(path)
    mid = comp.s1.points.shape[1] // 2
    z_mid = float(comp.s1.points[:, mid, 2].mean())
    c = comp.centre_s3[:2]
    design_r = float(np.median(np.hypot(*(comp.s3[:, :2] - c).T)))
    cyl = comp.s1.closed_u
    fig, ax = plt.subplots(1, 2, figsize=(10, 4.6))
    curves = [("S1 probed outer", comp.s1.points[:, mid], "tab:blue", "-"),
              ("S2 actual target", comp.s2.points[:, mid], "tab:red", "-")]
    near = np.abs(comp.s3[:, 2] - z_mid) <= np.ptp(comp.s3[:, 2]) / 20 + 1e-9
    s3, s3r = comp.s3[near], comp.s3_registered[near]
    if cyl:
        def dev(p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            ang = np.arctan2(p[:, 1] - c[1], p[:, 0] - c[0])
            o = np.argsort(ang)
            return ang[o], (np.hypot(p[:, 0] - c[0], p[:, 1] - c[1]) - design_r)[o]

        for label, pts, color, ls in curves + [("S3 design", s3, "k", "-"),
                                              ("S3 registered", s3r, "tab:purple", "--")]:
            ang, d = dev(pts)
            r = design_r + exaggerate * d
            ax[0].plot(c[0] + r * np.cos(ang), c[1] + r * np.sin(ang), color=color, ls=ls,
                       lw=1.1, label=label)
            ax[1].plot(np.degrees(ang), d, color=color, ls=ls, lw=1.1, label=label)
        ax[1].set_xlabel("angle (deg)")
        ax[0].set_aspect("equal")
    else:
        k = int(np.argmax(np.abs(comp.s1.normals[:, mid].mean(axis=0))))
        p = [a for a in range(3) if a != k][0]
        base = float(np.median(s3[:, k]))
        for label, pts, color, ls in curves + [("S3 design", s3, "k", "-"),
                                              ("S3 registered", s3r, "tab:purple", "--")]:
            o = np.argsort(pts[:, p])
            ax[0].plot(pts[o, p], base + exaggerate * (pts[o, k] - base), color=color, ls=ls,
                       lw=1.1, label=label)
            ax[1].plot(pts[o, p], pts[o, k] - base, color=color, ls=ls, lw=1.1, label=label)
        ax[1].set_xlabel(f"{'xyz'[p]} ({unit})")
    dx, dy = comp.shift
    ax[0].annotate("", xy=c - exaggerate * np.array([dx, dy]), xytext=c,
                   arrowprops={"arrowstyle": "->", "color": "tab:red", "lw": 1.5})
    ax[0].plot(*c, "k+", ms=10)
    ax[0].set_title(f"section z = {z_mid:.1f} {unit}, deviations x{exaggerate:g}; "
                    f"shift dx={dx:+.4f}, dy={dy:+.4f} {unit}", fontsize=8)
    ax[0].set_xlabel(f"x ({unit})")
    ax[0].set_ylabel(f"y ({unit})" if cyl else f"{'xyz'[k]} ({unit}, magnified)")
    ax[1].set_ylabel(f"deviation from design ({unit})")
    ax[1].set_title(f"F = {comp.registration.mean_distance:.4f} {unit} "
                    f"(k = {comp.threshold:g}); stock {comp.info['stock_min']:.3f}.."
                    f"{comp.info['stock_max']:.3f}", fontsize=8)
    ax[1].legend(fontsize=7)
    ax[1].grid(alpha=0.3)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)
    return path
