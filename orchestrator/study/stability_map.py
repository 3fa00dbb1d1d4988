"""The simulated stability map: a (spindle speed x axial depth) grid of force/vibration co-simulations, the onset of
chatter per speed read from the grid, and the same onset from the semi-discretization and the zero-order solution.

A study of ``scenarios/chatter.toml`` (CuttingForce and ToolVibration in a loop; ``studies/stability_map.toml``) runs
each case and reduces it with ``chatter_growth`` over two windows, the third and the last quarter of the run
(0.1-0.15 s and 0.15-0.2 s for the scenario's 0.2 s, as ``milling-twin validate chatter``):

- ``growth_x``, ``growth_y``: the growth of the free vibration, the tool displacement sampled once per tooth period
  (``orchestrator/validation/chatter.py``: ``displacement_growth``), its spread in the second window over the first;
  ``growth`` is the larger of the two and the case is ``stable`` (1) when it is <= 1, else 0;
- ``chip_growth``: the RMS of the dynamic chip r(t) - r(t - tau) of the tip displacement in the second window over
  the first (:func:`dynamic_chip_growth`), where the forced response cancels at every step, not only in samples.

The map (``[study] post = "stability_map"`` runs it after the sweep with the options of ``[study.map]``, into the
study's folder; :func:`stability_map` on any summary), for each growth column named:

- the co-simulated onset per speed: going up in depth, the first unstable case and the stable case below it bracket
  the onset; the depth where log(growth) crosses 0, interpolated linearly in depth between the two
  (:func:`onset_of`); not bracketed when every depth is stable (the onset is above the grid) or none is (below);
- the semi-discretization onset (``models.stability.semi_discretization_limit``, exact for the delay equation up to
  its step) and the zero-order onset (``models.stability.stability_lobes``, as ``milling-twin lobes``) at the same
  speeds, for the base scenario's tool, coefficients and immersion;
- a CSV (one row per speed: the three onsets in mm, the bracket and the relative differences), the same table
  printed, and a figure: every case coloured by its growth (circles stable, crosses chatter) over the zero-order
  and semi-discretization lobes, the co-simulated onsets marked (:func:`map_paths`: ``stability_map.csv``/``.png``
  for the first column, ``stability_map_<column>.csv``/``.png`` for the others).

``[study.map]`` keys (all optional): ``speed`` (the varied spindle speed, default ``"force.spindle_speed"``),
``depth`` (default ``"force.axial_depth"``), ``growth`` (a summary column or a list of them, default ``"growth"``),
``curve_points`` (speeds of the semi-discretization curve in the figure, default 120; 0 draws none),
``zoa_lobes`` (lobes of the zero-order curve, default 60).
"""
from __future__ import annotations

import csv
import importlib
import math
import threading
import time
from collections.abc import Mapping, Sequence
from concurrent.futures import Executor, Future
from dataclasses import dataclass
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from milling_twin.models.stability import semi_discretization_limit, stability_lobes
from milling_twin.orchestrator import atomic_files
from milling_twin.orchestrator.study.executor import submit_in_background
from milling_twin.orchestrator.study.post import register_post
from milling_twin.orchestrator.study.reduce import CaseRun, register
from milling_twin.orchestrator.study.refine import first_crossing
from milling_twin.orchestrator.validation.chatter import ToolAndCut, displacement_growth, tool_and_cut

if TYPE_CHECKING:
    import pandas as pd

    from milling_twin.orchestrator.scenario import Scenario
    from milling_twin.orchestrator.study.spec import Study

__all__ = ["MapConfig", "MapRow", "Onset", "chatter_growth", "curve_speeds", "dynamic_chip_growth",
           "dynamic_chip_rms", "feed_per_tooth", "growth_windows", "map_config", "map_paths", "map_rows", "onset_of",
           "onsets", "plot_map", "prepare_map", "references", "sd_curve", "sd_limits", "speed_range", "stability_map",
           "submit_sd_limits", "table_text", "write_csv"]

RPM = 60.0 / (2 * math.pi)  # rad/s -> rpm


def growth_windows(start_time: float, stop_time: float) -> tuple[tuple[float, float], tuple[float, float]]:
    """The two windows of the growth: the third and the last quarter of the run ((0.1, 0.15), (0.15, 0.2) for 0.2 s)."""
    span = stop_time - start_time
    return ((start_time + 0.5 * span, start_time + 0.75 * span), (start_time + 0.75 * span, stop_time))


def dynamic_chip_rms(scenario: Scenario, frame: pd.DataFrame,
                     windows: Sequence[tuple[float, float]]) -> list[float]:
    """The RMS of the dynamic chip e(t) = r(t) - r(t - tau) (r: the tool tip displacement in x and y, tau: the tooth
    period) in each of ``windows`` [s], m. The forced response repeats every tooth period and cancels in e at every
    output step, so e is the regenerative (free) vibration alone. r(t - tau) between output steps is a cubic
    spline's: a linear one leaves about (omega h)^2 / 8 of the forced response in e where tau is no multiple of
    the output step h (3e-4 of it at 850 Hz and 10 us, as large as a decayed free vibration), so the growth
    of a stable cut levelled off at 1 and crossed it by chance (25500 rpm on the 922 Hz tool)."""
    from scipy.interpolate import CubicSpline  # here: the command's process needs it only when it runs cases itself

    force = scenario.instance("force")
    tau = 2 * math.pi / (int(force.parameters.get("n_flutes", 2)) * force.inputs["spindle_speed"])
    t = frame["time"].to_numpy(float)
    squares = np.zeros_like(t)
    delayed = t - tau
    defined = delayed >= t[0]  # e(t) from one tooth period after the start
    for axis in ("x", "y"):
        r = frame[f"vibration.tip_displacement_{axis}"].to_numpy(float)
        squares[defined] += (r[defined] - CubicSpline(t, r)(delayed[defined])) ** 2
    chosen = [squares[defined & (t >= start) & (t < stop)] for start, stop in windows]
    return [math.sqrt(float(np.mean(c))) if c.size else math.nan for c in chosen]  # NaN: no e(t) in the window


def dynamic_chip_growth(scenario: Scenario, frame: pd.DataFrame,
                        windows: tuple[tuple[float, float], tuple[float, float]]) -> float:
    """The RMS of the dynamic chip (:func:`dynamic_chip_rms`) in the second of ``windows`` over the first."""
    return _second_over_first(dynamic_chip_rms(scenario, frame, windows))


def _second_over_first(rms: Sequence[float]) -> float:
    if math.isnan(rms[0]) or math.isnan(rms[1]):
        return math.nan  # a window without a sample: no growth to tell
    return rms[1] / rms[0] if rms[0] > 0 else math.inf


# A dynamic chip whose RMS in the last window exceeds this share of the feed per tooth is chatter grown into a limit
# cycle (the tool leaves the cut over part of each revolution, which stops the growth): its growth is about 1. On
# the 922 Hz tool such cases had 1.3 and 3.2 times the feed per tooth; stable cases near the onset at most 0.02.
LIMIT_CYCLE_CHIP = 0.5


def feed_per_tooth(scenario: Scenario) -> float:
    """The force instance's feed per tooth [m]: its feed velocity (x, y) over the tooth passing frequency."""
    force = scenario.instance("force")
    tau = 2 * math.pi / (int(force.parameters.get("n_flutes", 2)) * force.inputs["spindle_speed"])
    return math.hypot(float(force.inputs.get("feed_velocity_x", 0.0)),
                      float(force.inputs.get("feed_velocity_y", 0.0))) * tau


@register("chatter_growth")
def chatter_growth(case: CaseRun) -> dict[str, float]:
    """``growth_x``, ``growth_y``, ``growth`` (the larger), ``stable`` (1 when growth <= 1, else 0),
    ``chip_growth`` (:func:`dynamic_chip_growth`) and ``chip_rms`` (m: the dynamic chip's RMS in the second window)
    of one case, over :func:`growth_windows`. A limit cycle (``chip_rms`` above ``LIMIT_CYCLE_CHIP`` times the feed
    per tooth: chatter whose growth the cut's nonlinearity has stopped at about 1) has as ``chip_growth`` the
    largest growth from one quarter of the run to the next, the growth while it still grew (inf when none is
    above 1)."""
    scenario = case.scenario
    windows = growth_windows(scenario.start_time, scenario.stop_time)
    gx, gy = displacement_growth(scenario, case.results, windows)
    growth = max(gx, gy)
    start, span = scenario.start_time, scenario.stop_time - scenario.start_time
    quarters = [(start + k * span / 4, start + (k + 1) * span / 4) for k in range(4)]  # the last two: ``windows``
    rms = dynamic_chip_rms(scenario, case.results, quarters)
    chip_growth = _second_over_first(rms[2:])
    if rms[3] > LIMIT_CYCLE_CHIP * feed_per_tooth(scenario):  # a limit cycle: the growth while it still grew
        grew = [g for g in (_second_over_first(rms[k:k + 2]) for k in range(3)) if g > 1.0]
        chip_growth = max(grew) if grew else math.inf
    return {"growth_x": float(gx), "growth_y": float(gy), "growth": float(growth), "stable": float(growth <= 1.0),
            "chip_growth": float(chip_growth), "chip_rms": float(rms[3])}


@dataclass(frozen=True)
class Onset:
    """The co-simulated onset at one speed: ``depth`` [m] interpolated in log growth between ``stable_depth`` and
    ``unstable_depth`` (NaN when not bracketed: ``note`` says why)."""

    speed_rpm: float
    depth: float
    stable_depth: float  # m: the deepest stable case below the first unstable one (NaN: none)
    unstable_depth: float  # m: the shallowest unstable case (NaN: none)
    note: str = ""


def onset_of(speed_rpm: float, depths: Sequence[float], growths: Sequence[float]) -> Onset:
    """The onset at one speed from its cases (any order): the first unstable depth going up (growth > 1) and the
    stable one below it; between them the depth where log(growth) is 0, linear in depth."""
    d = np.asarray(depths, dtype=float)
    g = np.asarray(growths, dtype=float)
    keep = np.isfinite(d) & ~np.isnan(g)
    order = np.argsort(d[keep], kind="stable")
    d, g = d[keep][order], g[keep][order]
    if d.size == 0:
        return Onset(speed_rpm, math.nan, math.nan, math.nan, "no case")
    crossing = first_crossing(d, g, 1.0)
    if crossing is None and not (g > 1.0).any():
        return Onset(speed_rpm, math.nan, float(d[-1]), math.nan, f"stable up to {d[-1] * 1e3:.4g} mm")
    if crossing is None:
        return Onset(speed_rpm, math.nan, math.nan, float(d[0]), f"chatter from {d[0] * 1e3:.4g} mm")
    i = crossing[1]
    low, high = float(d[i - 1]), float(d[i])
    note = "stable again above" if np.any(g[i + 1:] <= 1.0) else ""
    log_low = math.log(max(float(g[i - 1]), 1e-300))
    log_high = math.log(float(g[i])) if math.isfinite(g[i]) else math.inf
    if not math.isfinite(log_high) or log_high <= log_low:
        return Onset(speed_rpm, 0.5 * (low + high), low, high, note or "middle of the bracket")
    depth = low + (0.0 - log_low) / (log_high - log_low) * (high - low)
    return Onset(speed_rpm, depth, low, high, note)


def onsets(summary: pd.DataFrame, speed: str = "force.spindle_speed", depth: str = "force.axial_depth",
           growth: str = "growth") -> list[Onset]:
    """The onset at each speed of a study summary (one row per case; ``speed`` in rad/s, ``depth`` in m, SI as the
    scenario's values), in increasing speed. Rows whose ``status`` column is not "ok" are left out."""
    for column in (speed, depth, growth):
        if column not in summary.columns:
            raise KeyError(f"the summary has no column {column!r} (columns: {', '.join(map(str, summary.columns))})")
    rows = summary
    if "status" in rows.columns:
        rows = rows[rows["status"] == "ok"]
    result = []
    for omega, group in rows.groupby(speed, sort=True):
        result.append(onset_of(float(omega) * RPM, group[depth].to_numpy(float), group[growth].to_numpy(float)))
    return result


def _sd_arguments(tool: ToolAndCut, speed_rpm: float) -> tuple[Any, ...]:
    return (tool.modes_x, tool.modes_y, tool.ktc, tool.krc, tool.n_flutes, float(speed_rpm), tool.entry, tool.exit)


SD_PER_TASK = 5  # limits per task: tens of ms each, so that a task is a few tenths of a second, like the cases'


def submit_sd_limits(tool: ToolAndCut, speeds_rpm: Sequence[float], executor: Executor,
                     background: bool = False) -> dict[float, Future[float]]:
    """The semi-discretization onsets [m] at ``speeds_rpm`` as futures by speed, :data:`SD_PER_TASK` speeds per task
    on ``executor`` (each task costs a cluster's scheduler and client a few ms of CPU on the cores the workers use,
    2.3 to 3.6 ms a round trip in docs/studies.md); ``background``: behind every other task submitted
    (:func:`submit_in_background`)."""
    submit = partial(submit_in_background, executor) if background else executor.submit
    speeds = list(dict.fromkeys(map(float, speeds_rpm)))
    futures: dict[float, Future[float]] = {}
    for start in range(0, len(speeds), SD_PER_TASK):
        group = tuple(speeds[start:start + SD_PER_TASK])
        futures.update(_per_speed(submit(_sd_group, tool, group), group))
    return futures


def _sd_group(tool: ToolAndCut, speeds_rpm: tuple[float, ...]) -> list[float]:
    return [semi_discretization_limit(*_sd_arguments(tool, n)) for n in speeds_rpm]


def _per_speed(task: Future[list[float]], speeds_rpm: tuple[float, ...]) -> dict[float, Future[float]]:
    """One future per speed of a task computing several: each resolves with its limit (or the task's exception)."""
    futures = {n: Future() for n in speeds_rpm}

    def resolve(done: Future[list[float]]) -> None:
        if done.cancelled():
            for future in futures.values():
                future.cancel()
            return
        error = done.exception()
        for k, future in enumerate(futures.values()):
            if error is not None:
                future.set_exception(error)
            else:
                future.set_result(done.result()[k])
    task.add_done_callback(resolve)
    return futures


def sd_limits(tool: ToolAndCut, speeds_rpm: Sequence[float], executor: Executor | None = None,
              started: Mapping[float, Future[float]] | None = None) -> np.ndarray:
    """Semi-discretization onsets [m] at ``speeds_rpm``, one task per speed on ``executor`` (in order; in this
    process without one): each takes tens of milliseconds, the map needs about 140. ``started``: futures of some
    of them submitted earlier (:func:`submit_sd_limits`), used where a speed is exactly one of theirs."""
    speeds = [float(n) for n in speeds_rpm]
    values: dict[float, Future[float] | float] = dict(started or {})
    missing = [n for n in dict.fromkeys(speeds) if n not in values]
    if executor is None:
        values.update(zip(missing, _sd_group(tool, tuple(missing))))
    else:
        values.update(submit_sd_limits(tool, missing, executor))
    return np.array([v.result() if isinstance(v, Future) else v for v in (values[n] for n in speeds)], dtype=float)


def references(tool: ToolAndCut, speeds_rpm: Sequence[float], zoa_lobes: int = 60,
               executor: Executor | None = None,
               started: Mapping[float, Future[float]] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(semi-discretization, zero-order) onsets [m] at ``speeds_rpm`` for the tool, coefficients and immersion."""
    speeds = np.asarray(speeds_rpm, dtype=float)
    return sd_limits(tool, speeds, executor, started), _zero_order(tool, zoa_lobes).limit(speeds)


def _zero_order(tool: ToolAndCut, lobes: int):  # -> Lobes
    return stability_lobes(tool.modes_x, tool.modes_y, tool.ktc, tool.krc, tool.n_flutes, tool.entry, tool.exit,
                           lobes=lobes)


@dataclass(frozen=True)
class MapRow:
    """One speed of the map: the three onsets [m] and the co-simulated bracket."""

    speed_rpm: float
    cosim: float
    stable_depth: float
    unstable_depth: float
    sd: float
    zoa: float
    note: str

    @property
    def cosim_vs_sd(self) -> float:
        return self.cosim / self.sd - 1

    @property
    def zoa_vs_sd(self) -> float:
        return self.zoa / self.sd - 1

    @property
    def cosim_vs_zoa(self) -> float:
        return self.cosim / self.zoa - 1


def map_rows(found: Sequence[Onset], tool: ToolAndCut, zoa_lobes: int = 60) -> list[MapRow]:
    """The co-simulated onsets next to the semi-discretization and zero-order onsets at their speeds."""
    sd, zoa = references(tool, [o.speed_rpm for o in found], zoa_lobes)
    return [MapRow(o.speed_rpm, o.depth, o.stable_depth, o.unstable_depth, float(s), float(z), o.note)
            for o, s, z in zip(found, sd, zoa)]


CSV_COLUMNS = ("speed_rpm", "cosim_mm", "stable_mm", "unstable_mm", "sd_mm", "zoa_mm", "cosim_vs_sd_pct",
               "zoa_vs_sd_pct", "cosim_vs_zoa_pct", "note")


def _csv_values(row: MapRow) -> list[Any]:
    mm = lambda v: f"{v * 1e3:.6g}" if math.isfinite(v) else ""  # noqa: E731
    pct = lambda v: f"{100 * v:.3f}" if math.isfinite(v) else ""  # noqa: E731
    return [f"{row.speed_rpm:.6g}", mm(row.cosim), mm(row.stable_depth), mm(row.unstable_depth), mm(row.sd),
            mm(row.zoa), pct(row.cosim_vs_sd), pct(row.zoa_vs_sd), pct(row.cosim_vs_zoa), row.note]


def write_csv(rows: Sequence[MapRow], path: Path) -> None:
    """The table, one row per speed (depths in mm, differences in %; empty where not bracketed)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_files.writing(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(CSV_COLUMNS)
        writer.writerows(_csv_values(r) for r in rows)


def table_text(rows: Sequence[MapRow]) -> str:
    """The table as printed: onset per speed, co-simulation vs semi-discretization (SD) vs zero-order (ZOA)."""
    def mm(v: float) -> str:
        return f"{v * 1e3:9.4f}" if math.isfinite(v) else f"{'-':>9}"

    def pct(v: float) -> str:
        return f"{100 * v:+8.1f} %" if math.isfinite(v) else f"{'-':>10}"

    def bracket(r: MapRow) -> str:
        ends = [f"{v * 1e3:.4f}" if math.isfinite(v) else "-" for v in (r.stable_depth, r.unstable_depth)]
        return f"{ends[0] + '-' + ends[1]:>15}"

    lines = [f"{'speed':>7} {'co-sim':>9} {'bracket':>15} {'SD':>9} {'ZOA':>9} {'co-sim/SD':>10} {'ZOA/SD':>10} "
             f"{'co-sim/ZOA':>10}",
             f"{'[rpm]':>7} {'[mm]':>9} {'[mm]':>15} {'[mm]':>9} {'[mm]':>9}"]
    for r in rows:
        lines.append(f"{r.speed_rpm:7.0f} {mm(r.cosim)} {bracket(r)} {mm(r.sd)} {mm(r.zoa)} {pct(r.cosim_vs_sd)} "
                     f"{pct(r.zoa_vs_sd)} {pct(r.cosim_vs_zoa)}" + (f"  {r.note}" if r.note else ""))
    bracketed = [r for r in rows if math.isfinite(r.cosim)]
    if bracketed:
        worst = max(bracketed, key=lambda r: abs(r.cosim_vs_sd))
        worst_zoa = max(bracketed, key=lambda r: abs(r.zoa_vs_sd))
        within = sum(abs(r.cosim_vs_sd) <= 0.05 for r in bracketed)
        lines.append(f"co-sim within 5 % of SD at {within} of {len(bracketed)} bracketed speeds; largest "
                     f"{100 * worst.cosim_vs_sd:+.1f} % at {worst.speed_rpm:.0f} rpm; ZOA vs SD largest "
                     f"{100 * worst_zoa.zoa_vs_sd:+.1f} % at {worst_zoa.speed_rpm:.0f} rpm")
    return "\n".join(lines)


def speed_range(cases: pd.DataFrame, speed: str) -> tuple[float, float]:
    """The figure's speed axis [rpm]: the cases' speeds and 3 % of their range either side."""
    return _speed_axis(cases[speed].to_numpy(float) * RPM)


def _speed_axis(n: np.ndarray) -> tuple[float, float]:
    low, high = (float(np.min(n)), float(np.max(n))) if n.size else (1.0, 2.0)
    margin = 0.03 * (high - low) if high > low else 0.05 * high
    return low - margin, high + margin


def curve_speeds(speeds: tuple[float, float], points: int) -> np.ndarray:
    """The speeds [rpm] of the semi-discretization curve of the figure: ``points`` evenly over ``speeds``."""
    return np.linspace(speeds[0], speeds[1], points)


def sd_curve(tool: ToolAndCut, speeds: tuple[float, float], points: int, executor: Executor | None = None,
             started: Mapping[float, Future[float]] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(speeds [rpm], semi-discretization onsets [m]) at ``points`` speeds evenly over ``speeds``."""
    n = curve_speeds(speeds, points)
    return n, sd_limits(tool, n, executor, started)


def plot_map(path: Path, cases: pd.DataFrame, rows: Sequence[MapRow], tool: ToolAndCut, speed: str, depth: str,
             growth: str = "growth", sd: tuple[np.ndarray, np.ndarray] | None = None, zoa_lobes: int = 60,
             title: str = "") -> None:
    """Every case at (speed, depth) coloured by its growth (circles stable, crosses chatter, grey triangles failed)
    over the zero-order lobes and the semi-discretization curve ``sd`` (:func:`sd_curve`; None: not drawn); the
    co-simulated onsets as diamonds."""
    from matplotlib.colors import TwoSlopeNorm
    from matplotlib.figure import Figure

    failed = cases[cases["status"] != "ok"] if "status" in cases.columns else cases.iloc[:0]
    ok = cases[cases["status"] == "ok"] if "status" in cases.columns else cases
    n = ok[speed].to_numpy(float) * RPM
    a = ok[depth].to_numpy(float) * 1e3
    g = ok[growth].to_numpy(float)
    log_g = np.log10(np.clip(np.nan_to_num(g, nan=1.0, posinf=1e6), 1e-6, 1e6))
    finite = log_g[np.isfinite(g)]
    span = max(1e-3, float(np.max(np.abs(finite)))) if finite.size else 1.0
    log_g = np.clip(log_g, -span, span)  # an infinite growth (a limit cycle) at the top of the scale
    norm = TwoSlopeNorm(vcenter=0.0, vmin=-span, vmax=span)
    low, high = speed_range(cases, speed)
    fig = Figure(figsize=(10, 5.5), layout="constrained")
    ax = fig.subplots()
    dense = np.linspace(low, high, 1500)
    ax.plot(dense, _zero_order(tool, zoa_lobes).limit(dense) * 1e3, color="black", lw=1.1,
            label="zero-order (ZOA) lobes")
    if sd is not None:
        ax.plot(sd[0], sd[1] * 1e3, color="tab:blue", lw=1.1, ls="--", label="semi-discretization (SD)")
    stable = g <= 1.0
    scatter = ax.scatter(n[stable], a[stable], c=log_g[stable], cmap="coolwarm", norm=norm, marker="o", s=26,
                         edgecolors="black", linewidths=0.4, label="co-simulation: stable", zorder=4)
    ax.scatter(n[~stable], a[~stable], c=log_g[~stable], cmap="coolwarm", norm=norm, marker="X", s=34,
               edgecolors="black", linewidths=0.3, label="co-simulation: chatter", zorder=4)
    if len(failed):
        ax.scatter(failed[speed].to_numpy(float) * RPM, failed[depth].to_numpy(float) * 1e3, marker="^", s=26,
                   color="0.6", edgecolors="black", linewidths=0.3, zorder=4,
                   label=f"co-simulation failed ({len(failed)}; the summary has the errors)")
    found = [r for r in rows if math.isfinite(r.cosim)]
    ax.scatter([r.speed_rpm for r in found], [r.cosim * 1e3 for r in found], marker="D", s=30, facecolors="none",
               edgecolors="tab:green", linewidths=1.4, label=f"co-simulated onset ({growth} = 1)", zorder=5)
    fig.colorbar(scatter, ax=ax, label=f"log10 {growth} (free vibration)")
    ax.set_xlim(low, high)
    top = float(cases[depth].max()) * 1e3 if len(cases) else 1.0
    ax.set_ylim(0, 1.08 * top)
    ax.set_xlabel("spindle speed [rpm]")
    ax.set_ylabel("axial depth of cut [mm]")
    ax.set_title(title or "Simulated stability map: co-simulated cases over the ZOA and SD lobes", fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_files.write_with(path, lambda tmp: fig.savefig(tmp, dpi=110, format="png"))


@dataclass(frozen=True)
class MapConfig:
    """The ``[study.map]`` table (see the module docstring)."""

    speed: str = "force.spindle_speed"
    depth: str = "force.axial_depth"
    growth: tuple[str, ...] = ("growth",)  # summary columns, one map each; the first names the files without suffix
    curve_points: int = 120
    zoa_lobes: int = 60


def map_config(table: Mapping[str, Any], where: str) -> MapConfig:
    """``[study.map]`` read from ``table``; errors name ``where`` (the study file) and the key."""
    if not isinstance(table, Mapping):
        raise ValueError(f"{where}: [study.map]: expected a table, got {table!r}")
    fields = MapConfig.__dataclass_fields__
    values: dict[str, Any] = {}
    for key, value in table.items():
        if key not in fields:
            raise ValueError(f"{where}: [study.map].{key}: unknown key; known: {', '.join(fields)}")
        default = getattr(MapConfig, key)
        if key == "growth":
            columns = [value] if isinstance(value, str) else value
            if not isinstance(columns, list) or not columns or not all(isinstance(c, str) and c for c in columns):
                raise ValueError(f"{where}: [study.map].growth = {value!r}: expected a summary column or a list "
                                 "of them")
            value = tuple(columns)
        elif isinstance(default, str):
            if not isinstance(value, str) or value.count(".") < 1:
                raise ValueError(f"{where}: [study.map].{key} = {value!r}: expected 'instance.variable'")
        elif isinstance(value, bool) or not isinstance(value, int) or value < (0 if key == "curve_points" else 1):
            raise ValueError(f"{where}: [study.map].{key} = {value!r}: expected an integer >= "
                             f"{0 if key == 'curve_points' else 1}")
        values[key] = value
    return MapConfig(**values)


def map_paths(out_dir: Path, growth: str, first: bool) -> tuple[Path, Path]:
    """(CSV, figure) of the map of one growth column: ``stability_map.csv``/``.png`` for the first column of
    ``[study.map].growth``, ``stability_map_<column>.csv``/``.png`` for the others."""
    stem = "stability_map" if first else f"stability_map_{growth}"
    return out_dir / f"{stem}.csv", out_dir / f"{stem}.png"


def stability_map(summary: pd.DataFrame, base: Scenario, out_dir: Path, config: MapConfig = MapConfig(),
                  echo: bool = True, executor: Executor | None = None,
                  started: Mapping[float, Future[float]] | None = None) -> dict[str, list[MapRow]]:
    """The maps of a finished study, one per growth column of ``config``: onsets per speed (co-sim, SD, ZOA) in a CSV
    (printed when ``echo``) and a figure (:func:`map_paths`). ``base``: the study's base scenario (its tool);
    ``executor``: where the semi-discretization limits are computed (the study's workers; None: here); ``started``:
    limits submitted before (:func:`prepare_map`)."""
    t0 = time.perf_counter()
    tool = tool_and_cut(base)
    failed = int((summary["status"] != "ok").sum()) if "status" in summary.columns else 0
    speeds = [o.speed_rpm for o in onsets(summary, config.speed, config.depth, config.growth[0])]
    reference = dict(zip(speeds, zip(*references(tool, speeds, config.zoa_lobes, executor, started))))
    curve = (sd_curve(tool, speed_range(summary, config.speed), config.curve_points, executor, started)
             if config.curve_points else None)
    maps: dict[str, list[MapRow]] = {}
    for k, growth in enumerate(config.growth):
        found = onsets(summary, config.speed, config.depth, growth)
        rows = [MapRow(o.speed_rpm, o.depth, o.stable_depth, o.unstable_depth, float(reference[o.speed_rpm][0]),
                       float(reference[o.speed_rpm][1]), o.note) for o in found]
        csv_path, figure = map_paths(out_dir, growth, k == 0)
        write_csv(rows, csv_path)
        plot_map(figure, summary, rows, tool, config.speed, config.depth, growth, curve, config.zoa_lobes,
                 title=f"Simulated stability map of {base.path.name} ({growth}): co-simulated cases "
                 "over the ZOA and SD lobes")
        if echo:
            print(f"onset of chatter per speed, co-simulation ({growth} = 1) vs semi-discretization (SD) vs "
                  "zero-order (ZOA):")
            print(table_text(rows))
            if failed:
                print(f"{failed} failed cases left out (their errors are in the summary)")
            print(f"map: {csv_path}, {figure} ({time.perf_counter() - t0:.1f} s since the map began)")
        maps[growth] = rows
    return maps


def prepare_map(study: Study, config: MapConfig, executor: Executor) -> dict[float, Future[float]]:
    """Before the cases run: the semi-discretization limits the map will need (at the study's speeds and along the
    figure's curve) submitted behind the cases, so that the workers compute them where they would wait (at the end
    of each refinement round, while this process draws) instead of after the sweep. A case whose values cannot be
    applied is left out (it fails when it runs)."""
    from milling_twin.orchestrator.scenario import with_values
    from milling_twin.orchestrator.study.run import si_inputs

    base = study.scenario()
    speeds = []
    for case in study.cases:
        try:
            value = si_inputs(with_values(base, case.values), (config.speed,))[config.speed]
        except Exception:  # noqa: BLE001 - the case's own run reports it
            continue
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            speeds.append(float(value) * RPM)
    if not speeds:
        return {}
    # matplotlib's import (0.26 s), in the background while the workers run: otherwise it comes at the end, before
    # the maps are drawn, when the workers have nothing left to do
    threading.Thread(target=_import_figure_modules, name="import matplotlib", daemon=True).start()
    rpm = np.unique(np.array(speeds))
    curve = curve_speeds(_speed_axis(np.array(speeds)), config.curve_points) if config.curve_points else []
    return submit_sd_limits(tool_and_cut(study.base), [*rpm, *curve], executor, background=True)


def _import_figure_modules() -> None:
    for module in ("matplotlib.figure", "matplotlib.colors", "matplotlib.backends.backend_agg"):
        importlib.import_module(module)


@register_post("stability_map", table="map", check=map_config, prepare=prepare_map)
def _post(summary: pd.DataFrame, study: Study, folder: Path, config: MapConfig, executor: Executor,
          started: Mapping[float, Future[float]]) -> None:
    """``[study] post = "stability_map"``: the maps of the finished sweep into its folder, the tables printed; the
    semi-discretization limits on the study's workers (submitted by :func:`prepare_map`)."""
    stability_map(summary, study.base, folder, config, executor=executor, started=started)
