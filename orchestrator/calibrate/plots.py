"""The report's figures as PNG bytes (matplotlib without pyplot: no global figure state)."""
from __future__ import annotations

import io
from collections.abc import Sequence

import numpy as np
from matplotlib.figure import Figure as MplFigure

from milling_twin.orchestrator.calibrate.lsq import StartOutcome
from milling_twin.orchestrator.calibrate.result import Series

__all__ = ["correlation_png", "fit_png", "residual_png", "trace_png"]


def _png(fig: MplFigure, dpi: int = 90) -> bytes:
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()


def fit_png(group: Sequence[Series]) -> bytes:
    """Recorded and simulated (before, after) with the errors below, one column per output of a group
    (one data set and label)."""
    n = len(group)
    fig = MplFigure(figsize=(4.2 * n + 2.8 if n > 1 else 10, 5.2))
    fig.subplots_adjust(left=0.08 if n == 1 else 0.06, right=0.98, top=0.86, bottom=0.1, wspace=0.28, hspace=0.08)
    axes = fig.subplots(2, n, sharex=True, height_ratios=[3, 1.3], squeeze=False)
    for c, series in enumerate(group):
        s = series.display_factor
        top, bottom = axes[0][c], axes[1][c]
        order = np.argsort(series.time, kind="stable")
        t = series.time[order]
        rec, before, after = series.recorded[order] * s, series.before[order] * s, series.after[order] * s
        style = dict(linewidth=0.9) if t.size > 200 else dict(linewidth=0.9, marker=".", markersize=3)
        top.plot(t, rec, color="tab:gray", label=f"recorded: {series.recorded_channel}", **style)
        top.plot(t, before, color="tab:orange", label="simulated, initial parameters", **style)
        top.plot(t, after, color="tab:blue", label="simulated, calibrated parameters", **style)
        top.set_ylabel(f"{series.output} [{series.display_unit}]", fontsize=8)
        top.set_title(f"{series.recorded_channel} vs {series.output}", fontsize=9)
        top.grid(True, alpha=0.3)
        bottom.plot(t, before - rec, color="tab:orange", **style)
        bottom.plot(t, after - rec, color="tab:blue", **style)
        bottom.axhline(0.0, color="black", linewidth=0.5)
        bottom.set_ylabel(f"error [{series.display_unit}]", fontsize=8)
        bottom.set_xlabel(series.x_label, fontsize=8)
        bottom.grid(True, alpha=0.3)
    axes[0][0].legend(loc="best", fontsize=7)
    first = group[0]
    fig.suptitle(f"{first.dataset} data{' ' + first.label if first.label else ''}", fontsize=10)
    return _png(fig)


def residual_png(group: Sequence[Series]) -> bytes:
    """Residuals after calibration, one row per output of a group: histogram, against the simulated
    value, and their autocorrelation."""
    fig = MplFigure(figsize=(10, 0.4 + 2.6 * len(group)))
    fig.subplots_adjust(left=0.08, right=0.98, top=1 - 0.45 / (0.4 + 2.6 * len(group)), bottom=0.12 / len(group) + 0.05,
                        wspace=0.3, hspace=0.55)
    rows = fig.subplots(len(group), 3, squeeze=False)
    for (hist, scatter, acf), series in zip(rows, group):
        s = series.display_factor
        residual = (series.after - series.recorded) * s
        hist.hist(residual, bins=min(60, max(10, residual.size // 20)), color="tab:blue", alpha=0.8)
        hist.set_xlabel(f"{series.output} residual [{series.display_unit}]", fontsize=8)
        hist.set_ylabel("samples", fontsize=8)
        hist.set_title(f"mean {residual.mean():.3g}, std {residual.std():.3g}", fontsize=8)
        scatter.plot(series.after * s, residual, ".", markersize=2, color="tab:blue")
        scatter.axhline(0.0, color="black", linewidth=0.5)
        scatter.set_xlabel(f"simulated [{series.display_unit}]", fontsize=8)
        scatter.set_ylabel("residual", fontsize=8)
        centred = residual - residual.mean()
        lags = min(50, max(residual.size - 1, 1))
        denom = float(centred @ centred) or 1.0
        values = [float(centred[: residual.size - k] @ centred[k:]) / denom for k in range(lags + 1)]
        acf.bar(range(lags + 1), values, color="tab:blue", width=0.8)
        acf.axhline(0.0, color="black", linewidth=0.5)
        acf.set_xlabel("lag [samples]", fontsize=8)
        acf.set_ylabel("autocorrelation", fontsize=8)
        for ax in (hist, scatter, acf):
            ax.grid(True, alpha=0.3)
    first = group[0]
    fig.suptitle(f"residuals after calibration, {first.dataset} data{' ' + first.label if first.label else ''}",
                 fontsize=10)
    return _png(fig)


def correlation_png(names: Sequence[str], correlation: np.ndarray) -> bytes:
    n = len(names)
    fig = MplFigure(figsize=(1.6 + 0.75 * n, 1.2 + 0.65 * n))
    fig.subplots_adjust(left=0.25, right=0.95, top=0.95, bottom=0.25)
    ax = fig.subplots()
    shown = np.nan_to_num(correlation, nan=0.0)
    image = ax.imshow(shown, vmin=-1, vmax=1, cmap="coolwarm")
    for i in range(n):
        for j in range(n):
            text = "n/a" if not np.isfinite(correlation[i, j]) else f"{correlation[i, j]:+.2f}"
            ax.text(j, i, text, ha="center", va="center", fontsize=8)
    ax.set_xticks(range(n), [x.split(".", 1)[-1] for x in names], rotation=45, ha="right", fontsize=8)
    ax.set_yticks(range(n), [x.split(".", 1)[-1] for x in names], fontsize=8)
    fig.colorbar(image, ax=ax, shrink=0.8)
    return _png(fig)


def trace_png(starts: Sequence[StartOutcome], best: int) -> bytes:
    """Objective over IPOPT iterations for every start (the chosen one bold)."""
    fig = MplFigure(figsize=(8, 3.4))
    fig.subplots_adjust(left=0.1, right=0.98, top=0.95, bottom=0.15)
    ax = fig.subplots()
    for o in starts:
        obj = np.asarray(o.trace.get("obj", []), dtype=float)
        if obj.size:
            ax.semilogy(np.arange(obj.size), np.maximum(obj, 1e-300), linewidth=2.2 if o.index == best else 0.9,
                        label=f"start {o.index}: {o.status}")
    ax.set_xlabel("IPOPT iteration")
    ax.set_ylabel("objective 0.5*|r|^2")
    ax.grid(True, alpha=0.3, which="both")
    if any(o.trace.get("obj") for o in starts):
        ax.legend(fontsize=7, loc="best")
    return _png(fig)
