"""The report's figures as PNG bytes (matplotlib without pyplot: no global figure state)."""
from __future__ import annotations

import io
from collections.abc import Sequence

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure as MplFigure
from matplotlib.ticker import ScalarFormatter

from milling_twin.orchestrator.calibrate.lsq import StartOutcome
from milling_twin.orchestrator.calibrate.result import Series

__all__ = ["correlation_png", "figure_png", "fit_figure", "fit_png", "residual_figure", "residual_png", "trace_png"]


CONSTANT = 1e-6  # an axis whose data span is below this fraction of its magnitude is drawn as constant
ROUNDING = 1e-9  # ... or below this fraction of the reference magnitude (errors against the data they are errors of)


def _readable(ax: Axes, x_reference: float = 0.0, y_reference: float = 0.0) -> None:
    """Tick labels that say the values: no offset text on linear axes (matplotlib's "1e-9+1.7695e2"
    lands over the axis label), and an axis whose data are constant, or nearly (span below CONSTANT of
    their magnitude, or below ROUNDING of ``*_reference``, e.g. the size of the recorded values for an axis
    of errors), spans +-5 % of that magnitude around them (+-1 at 0) instead of ticks that differ in the
    tenth digit or a range matplotlib picks for nothing."""
    for axis, interval, reference, set_lim in ((ax.xaxis, ax.dataLim.intervalx, x_reference, ax.set_xlim),
                                               (ax.yaxis, ax.dataLim.intervaly, y_reference, ax.set_ylim)):
        formatter = axis.get_major_formatter()
        if not isinstance(formatter, ScalarFormatter):  # log axes, named ticks
            continue
        formatter.set_useOffset(False)
        lo, hi = (float(v) for v in interval)
        if not (np.isfinite(lo) and np.isfinite(hi)) or hi < lo:  # no data
            continue
        magnitude = max(abs(lo), abs(hi))
        if hi - lo <= CONSTANT * magnitude or hi - lo <= ROUNDING * abs(reference):
            pad = 0.05 * max(magnitude, abs(reference)) or 1.0
            set_lim((lo + hi) / 2 - pad, (lo + hi) / 2 + pad)


def _scale(*values: np.ndarray) -> float:
    """The largest finite magnitude among ``values`` (0 if none)."""
    finite = [np.abs(v[np.isfinite(v)]) for v in values]
    return max((float(f.max()) for f in finite if f.size), default=0.0)


def figure_png(fig: MplFigure, dpi: int = 90) -> bytes:
    """The figure as PNG, every axis made readable first (:func:`_readable`, no reference: a caller
    that knows one calls it before)."""
    for ax in fig.axes:
        _readable(ax)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=dpi)
    return buffer.getvalue()


def fit_png(group: Sequence[Series]) -> bytes:
    return figure_png(fit_figure(group))


def fit_figure(group: Sequence[Series]) -> MplFigure:
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
        _readable(bottom, y_reference=_scale(rec, before, after))
    axes[0][0].legend(loc="best", fontsize=7)
    first = group[0]
    fig.suptitle(f"{first.dataset} data{' ' + first.label if first.label else ''}", fontsize=10)
    return fig


def residual_png(group: Sequence[Series]) -> bytes:
    return figure_png(residual_figure(group))


def residual_figure(group: Sequence[Series]) -> MplFigure:
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
        size = _scale(series.recorded * s, series.after * s)
        _readable(hist, x_reference=size)
        _readable(scatter, y_reference=size)
    first = group[0]
    fig.suptitle(f"residuals after calibration, {first.dataset} data{' ' + first.label if first.label else ''}",
                 fontsize=10)
    return fig


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
    return figure_png(fig)


def trace_png(starts: Sequence[StartOutcome], best: int) -> bytes:
    """Objective over the solver's iterations for every start (the chosen one bold)."""
    fig = MplFigure(figsize=(8, 3.4))
    fig.subplots_adjust(left=0.1, right=0.98, top=0.95, bottom=0.15)
    ax = fig.subplots()
    for o in starts:
        obj = np.asarray(o.trace.get("obj", []), dtype=float)
        if obj.size:
            ax.semilogy(np.arange(obj.size), np.maximum(obj, 1e-300), linewidth=2.2 if o.index == best else 0.9,
                        label=f"start {o.index}: {o.status}")
    ax.set_xlabel("solver iteration")
    ax.set_ylabel("objective 0.5*|r|^2")
    ax.grid(True, alpha=0.3, which="both")
    if any(o.trace.get("obj") for o in starts):
        ax.legend(fontsize=7, loc="best")
    return figure_png(fig)
