"""The optimizer's report: ``optimize_report.html`` (self-contained) and ``blocks_before_after.csv``.

The page: the headline (cycle time and peak force before and after, the limits, why the iteration stopped), the
iterations, a figure of each line's feed and largest force before and after against its limit, the table of
every program line with feed moves before and after (feed, time, force, torque, spindle power, deflection,
chatter), and the changed lines of the program as a diff. The CSV holds the same table in display units.
"""
from __future__ import annotations

import difflib
import html
import math
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from milling_twin.orchestrator import atomic_files
from milling_twin.orchestrator.optimize.schedule import ToolLimits, line_runs
from milling_twin.orchestrator.optimize.spec import OptimizeSpec
from milling_twin.orchestrator.optimize.sub_blocks import SplitProgram
from milling_twin.orchestrator.part.plots import _png
from milling_twin.orchestrator.part.report import STYLE, _html_table, _img

__all__ = ["write_optimize_report", "before_after"]

INSERTED = " and sub-blocks are inserted above the line they are part of, each with a comment naming it"
MAX_DIFF_LINES = 2000   # lines of the diff shown on the page (the programs themselves are files beside it)
DIFF_STYLE = """pre.diff{font-size:0.8em;background:#fafafa;border:1px solid #ddd;padding:0.5em;overflow-x:auto}
pre.diff .add{background:#e3f6e3} pre.diff .del{background:#fde2e2} pre.diff .hunk{color:#557}"""


def before_after(before: pd.DataFrame, after: pd.DataFrame, original_feeds: Mapping[int, float],
                 tool_of=int, split: tuple[SplitProgram, Mapping[int, float]] | None = None) -> pd.DataFrame:
    """One row per program line with feed moves: the original run's and the optimized run's values (SI).
    ``split``: the optimized program has sub-blocks: the split program and its lines' feeds before optimizing;
    then a row per line of it, the original line's values before (the whole line's)."""
    lines = sorted(original_feeds)
    a = line_runs(before, original_feeds, lines, tool_of)
    after_feeds = original_feeds if split is None else split[1]
    b = line_runs(after, after_feeds, sorted(after_feeds), tool_of)
    rows = []
    for new in sorted(after_feeds):
        line = new if split is None else split[0].origin[new]
        if line not in a or new not in b:
            continue
        x, y = a[line], b[new]
        part = None if split is None else split[0].parts.get(new)
        rows.append({"line": line, "sub_block": f"{part[0]}/{part[1]}" if part else "", "tool": x.tool,
                     "cuts": x.cuts, "feed_before": x.feed, "feed_after": y.feed,
                     "factor": y.factor, "time_before": x.duration, "time_after": y.duration,
                     **{f"{name}_before": x.metrics[name] for name in x.metrics},
                     **{f"{name}_after": y.metrics[name] for name in y.metrics},
                     "chatter_before": x.chatter, "chatter_after": y.chatter})
    return pd.DataFrame(rows)


# column -> (header, factor from SI to the display unit, digits)
_DISPLAY = {
    "line": ("line", 1, 0), "sub_block": ("sub-block", 1, 0), "tool": ("tool", 1, 0), "cuts": ("cuts", 1, 0),
    "feed_before": ("F before [mm/min]", 60000.0, 1), "feed_after": ("F after [mm/min]", 60000.0, 1),
    "factor": ("factor", 1.0, 3),
    "time_before": ("time before [s]", 1.0, 3), "time_after": ("time after [s]", 1.0, 3),
    "force_before": ("force max before [N]", 1.0, 1), "force_after": ("force max after [N]", 1.0, 1),
    "torque_before": ("torque max before [N.m]", 1.0, 3), "torque_after": ("torque max after [N.m]", 1.0, 3),
    "power_before": ("spindle power max before [kW]", 1e-3, 3),
    "power_after": ("spindle power max after [kW]", 1e-3, 3),
    "deflection_before": ("deflection max before [um]", 1e6, 2),
    "deflection_after": ("deflection max after [um]", 1e6, 2),
    "chatter_before": ("chatter before", 1, 0), "chatter_after": ("chatter after", 1, 0),
}


def _display(table: pd.DataFrame) -> pd.DataFrame:
    out = {}
    for column, (header, factor, _) in _DISPLAY.items():
        values = table[column]
        out[header] = values * factor if factor != 1 or values.dtype.kind == "f" else values
    return pd.DataFrame(out)


def _cell(value, digits: int) -> str:
    if isinstance(value, str):
        return value
    if isinstance(value, (bool, np.bool_)):
        return "yes" if value else ""
    if isinstance(value, (int, np.integer)):
        return str(int(value))
    return "" if not math.isfinite(float(value)) else f"{float(value):.{digits}f}"


def _figure(table: pd.DataFrame, limits: Mapping[int, ToolLimits], force_scale: float) -> bytes:
    fig = Figure(figsize=(11, 6.5))
    top, bottom = fig.subplots(2, 1, sharex=True)
    x = np.arange(len(table))
    top.step(x, table["feed_before"] * 60000, where="mid", label="before", color="#888")
    top.step(x, table["feed_after"] * 60000, where="mid", label="after", color="#1f5fbf")
    top.set_ylabel("programmed feed [mm/min]")
    top.legend(loc="upper right")
    top.grid(alpha=0.3)
    bottom.bar(x - 0.2, table["force_before"], width=0.4, label="before", color="#aaa")
    bottom.bar(x + 0.2, table["force_after"], width=0.4, label="after", color="#1f5fbf")
    for tool, lim in limits.items():
        force = lim.process.get("force")
        if force is not None:
            bottom.axhline(force * force_scale, color="#c33", lw=1, ls="--", label=f"T{tool} force limit")
    bottom.set_ylabel("largest force [N]")
    bottom.set_xlabel("program lines with feed moves, in program order (69.1: sub-block 1 of line 69)")
    step = max(1, len(x) // 25)
    labels = [f"{line}.{part.split('/')[0]}" if part else str(line)
              for line, part in zip(table["line"], table["sub_block"])]
    bottom.set_xticks(x[::step], labels[::step], rotation=90, fontsize=7)
    bottom.legend(loc="upper right", fontsize=8)
    bottom.grid(alpha=0.3)
    fig.tight_layout()
    return _png(fig)


def _speed_map_figure(choice) -> bytes:
    """A chattering tool's simulated map: the dynamic chip per speed, stable or not, the two speeds marked."""
    from milling_twin.orchestrator.optimize.speed_map import LIMIT_CYCLE_CHIP

    fig = Figure(figsize=(10, 4))
    ax = fig.subplots()
    speed_map = choice.map
    speeds = np.asarray(speed_map.speeds)
    chip = np.asarray(speed_map.chip, dtype=float)
    finite = np.isfinite(chip) & (chip > 0)
    top = 10.0 * max(float(chip[finite].max()) if finite.any() else 1.0, LIMIT_CYCLE_CHIP)
    shown = np.where(finite, chip, top)   # a case that diverged (or failed) at the top of the axis
    stable = np.asarray(speed_map.stable)
    ax.semilogy(speeds, shown, color="#888", lw=0.8)
    ax.scatter(speeds[stable], shown[stable], color="#1f5fbf", zorder=3, label="stable")
    ax.scatter(speeds[~stable], shown[~stable], facecolors="none", edgecolors="#c33", zorder=3,
               label="chatter (at the top: the vibration diverged)")
    ax.axhline(LIMIT_CYCLE_CHIP, color="#c33", lw=0.8, ls=":")
    ax.axvline(choice.programmed, color="#555", ls="--", label=f"programmed {choice.programmed:.0f} rpm")
    ax.axvline(choice.chosen, color="#1f5fbf", ls="-", label=f"chosen {choice.chosen:.0f} rpm")
    ax.set_xlabel("spindle speed [rpm]")
    ax.set_ylabel("dynamic chip RMS / feed per tooth")
    ax.grid(alpha=0.3)
    ax.legend(loc="lower left", fontsize=8)
    fig.tight_layout()
    return _png(fig)


def _diff_html(before: str, after: str, name: str) -> tuple[str, int]:
    diff = list(difflib.unified_diff(before.splitlines(), after.splitlines(), f"{name} (original)",
                                     f"{name} (optimized)", lineterm="", n=1))
    shown = diff[:MAX_DIFF_LINES]
    out = []
    for text in shown:
        cls = "add" if text.startswith("+") and not text.startswith("+++") else \
            "del" if text.startswith("-") and not text.startswith("---") else "hunk" if text.startswith("@@") else ""
        out.append(f"<span class='{cls}'>{html.escape(text)}</span>" if cls else html.escape(text))
    more = "" if len(diff) <= MAX_DIFF_LINES else f"\n... {len(diff) - MAX_DIFF_LINES} more lines of the diff"
    return "<pre class='diff'>" + "\n".join(out) + html.escape(more) + "</pre>", len(diff)


def write_optimize_report(folder: Path, part, spec: OptimizeSpec, limits: Mapping[int, ToolLimits],
                          iterations: Sequence, best, original_text: str, optimized_text: str,
                          stopped: str, original_feeds: Mapping[int, float], tool_of: Callable[[int], int],
                          speeds: Mapping = (), split: tuple[SplitProgram, Mapping[int, float]] | None = None) -> Path:
    """Write the page and the CSV into ``folder``; the page's path. ``original_feeds``: each feed-move line's
    programmed feed in the original (m/s); ``tool_of``: the cutting tool of a block's tool number; ``split``: the
    best program has sub-blocks (see :func:`before_after`)."""
    original = iterations[0]
    before = pd.read_parquet(original.run_dir / "blocks.parquet")
    after = pd.read_parquet(best.run_dir / "blocks.parquet")
    table = before_after(before, after, original_feeds, tool_of, split)
    atomic_files.write_with(folder / "blocks_before_after.csv", lambda p: _display(table).to_csv(p, index=False,
                                                                                        float_format="%.6g"))

    t0, t1 = original.cycle_time, best.cycle_time
    p0, p1 = max(original.peak_force.values(), default=0.0), max(best.peak_force.values(), default=0.0)
    title = f"Feed optimization: {part.program.name}"
    head = [["objective", "the shortest cycle within the limits" if spec.objective == "time"
             else "the original cycle time with the lowest peak force"],
            ["cycle time", f"{t0:.2f} s -> {t1:.2f} s ({(t1 / t0 - 1) * 100:+.1f} %)" if original.status == "completed"
             else f"the original's run did not complete ({original.status[:200]}): {t0:.2f} s of it; the "
                  f"optimized program {t1:.2f} s"],
            ["largest force", f"{p0:.1f} N -> {p1:.1f} N ({(p1 / p0 - 1) * 100:+.1f} %)" if p0 > 0 else "none"],
            ["best run", f"iteration {best.number} of {len(iterations) - 1} ({stopped})"],
            ["lines with feed moves", f"{len(original_feeds)}, "
                                      f"{len({line for line, f in zip(table['line'], table['factor']) if f != 1.0})}"
                                      f" with a new feed"],
            ["sub-blocks", f"{len(split[0].plans)} lines split into {len(split[0].parts)} sub-blocks where their "
                           f"engagement changes" if split else "none"]]
    summary = "<table class='summary'>" + "".join(
        f"<tr><td><b>{html.escape(a)}</b></td><td>{html.escape(b)}</td></tr>" for a, b in head) + "</table>"
    limit_rows = []
    for tool, lim in limits.items():
        process = {k: v * (best.force_scale if k == "force" else 1.0) for k, v in lim.process.items()}
        limit_rows.append([f"T{tool}", f"{process['force']:.1f}" if "force" in process else "",
                           f"{process['torque']:.3f}" if "torque" in process else "",
                           f"{process['power'] / 1e3:.2f}" if "power" in process else "",
                           f"{process['deflection'] * 1e6:.1f}" if "deflection" in process else "",
                           f"{lim.feed_per_tooth_min * 1e3:.4f}", f"{lim.feed_per_tooth_max * 1e3:.4f}"
                           if math.isfinite(lim.feed_per_tooth_max) else "", f"{lim.feed * 60000:.0f}",
                           str(lim.flutes)])
    limits_html = _html_table(["tool", "force [N]", "torque [N.m]", "spindle power [kW]", "deflection [um]",
                               "fz min [mm]", "fz max [mm]", "feed max [mm/min]", "flutes"], limit_rows)
    speed_rows = [[f"T{c.tool}", f"{c.programmed:.0f}", f"{c.chosen:.0f}", c.source, f"{c.depth * 1e3:.3f}",
                   _cell(c.chip_programmed, 4), _cell(c.chip_chosen, 4), f"{c.limit_programmed * 1e3:.3f}",
                   f"{c.limit_chosen * 1e3:.3f}", c.note] for c in dict(speeds).values()]
    maps = "".join(_img(_speed_map_figure(c), f"T{c.tool}: the simulated stability map",
                        f"The tool's force/vibration loop slotting {c.map.depth * 1e3:.3g} mm deep "
                        f"({1 + spec.stability_margin:g} x its deepest chattering cut) at each speed: the dynamic "
                        f"chip's RMS over the feed per tooth (filled: stable; dotted: the share above which a "
                        f"bounded vibration is chatter). The study files are in speeds/ beside this page "
                        f"({c.study.name} the last round).")
                   for c in dict(speeds).values() if c.map is not None)
    speeds_html = ("<h2>Spindle speeds</h2>" + _html_table(
        ["tool", "programmed [rpm]", "chosen [rpm]", "stable by", "deepest chattering cut [mm]",
         "dynamic chip at programmed [x fz]", "dynamic chip at chosen [x fz]", "zero-order limit at programmed [mm]",
         "zero-order limit at chosen [mm]", "note"], speed_rows) + "<p class='note'>A tool whose blocks chatter in "
        "the original run: the speed closest to the programmed one (within "
        f"{spec.speed_range[0]:g}..{spec.speed_range[1]:g} x) that is stable at {1 + spec.stability_margin:g} x "
        "its deepest chattering cut, in the tool's simulated stability map (its force/vibration loop over the "
        "speeds: \"simulated\") or by the zero-order slotting limit (\"zero-order\"); its feeds follow to keep "
        "the chip.</p>" + maps) if speed_rows else ""
    iteration_rows = [[str(it.number), f"{it.cycle_time:.3f}", f"{max(it.peak_force.values(), default=0):.1f}",
                       "yes" if it.feasible else f"no: {'; '.join(it.violations[:3])}"
                       + (f" (+{len(it.violations) - 3})" if len(it.violations) > 3 else ""),
                       f"{it.force_scale:.4g}", f"{it.wall_time:.1f}"] for it in iterations]
    iterations_html = _html_table(["iteration", "cycle time [s]", "largest force [N]", "every limit holds",
                                   "force scale", "run [s]"], iteration_rows)
    figure = _img(_figure(table, limits, best.force_scale), "Feed and largest force per program line",
                  "Top: the programmed feed of each line with feed moves, before (grey) and after (blue). Bottom: "
                  "the line's largest resultant force in the twin, before and after, and the force limit.") \
        if len(table) else ""
    digits = {header: d for _, (header, _, d) in _DISPLAY.items()}
    shown = _display(table)
    rows = [[_cell(v, digits[c]) for c, v in zip(shown.columns, row)] for row in shown.itertuples(index=False)]
    diff, n_diff = _diff_html(original_text, optimized_text, part.program.name)
    page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
            f"<style>{STYLE}\n{DIFF_STYLE}</style></head><body><h1>{html.escape(title)}</h1>{summary}"
            f"<h2>Limits</h2>{limits_html}<p class='note'>Each tool's limits in the re-simulation, within "
            f"{spec.tolerance * 100:g} %; a force limit not given is the original run's largest force of the tool"
            f"{' (times the scale of the best run: objective force)' if spec.objective == 'force' else ''}.</p>"
            f"{speeds_html}<h2>Iterations</h2>{iterations_html}{figure}"
            f"<h2>Program lines before and after</h2>{_html_table(list(shown.columns), rows)}"
            f"<h2>What changed in the program</h2><p class='note'>{n_diff} diff lines; only F words change"
            f"{INSERTED if split else ''}"
            f"; every original line is kept. The optimized program and each iteration's are files beside this "
            f"page.</p>"
            f"{diff}</body></html>")
    return atomic_files.write_text(folder / "optimize_report.html", page)
