"""The process report of a whole-part run: one self-contained HTML file (figures as PNG data URIs, inline
style, no scripts, no external references), the per-block table as Parquet (SI, units in the field metadata)
and CSV (display units in the headers), the machined part as binary STL (mm) and ``process_report.json`` with
the headline figures. What each column, figure and indicator means: docs/process_report.md.
Every file is written atomically (``orchestrator.atomic_files``): complete or unchanged, no temporary file left.
"""
from __future__ import annotations

import base64
import html
import json
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from milling_twin.orchestrator import atomic_files
from milling_twin.orchestrator.json_values import jsonable
from milling_twin.models.stability import stability_lobes
from milling_twin.models.units import conversion_factor
from milling_twin.orchestrator.part import chatter, plots
from milling_twin.orchestrator.part.blocks import (BY_NAME, COLUMNS, BlockColumn, Signals, Spans, block_spans,
                                                   block_table, program_lines, plunge_note,
                                                   write_block_table)
from milling_twin.orchestrator.part.model import FORCE, INTERPOLATOR, POWER, WORKPIECE, CutTool, Part
from milling_twin.orchestrator.part.surface import (ZMapGrid, analytic_volumes, load_zmap, surface_location_errors,
                                                    write_stl)

__all__ = ["ProcessReport", "write_process_report", "HTML_BLOCKS"]

HTML_BLOCKS = 200          # the HTML table shows the most loaded blocks up to this many; the CSV has all
LABELLED_BLOCKS = 8        # blocks named on the time-series figure (the largest resultant force)
VOLUME_AGREEMENT = 1e-9    # relative: the run's removed volume and stock - Z-map are the same cells
STL_MAX_CELLS = 2_000_000  # a larger Z-map gets no STL (200 MB, about 4 s to write)

# the block table's columns shown in the HTML (all are in the CSV and Parquet files)
HTML_COLUMNS = ("block", "line", "start_time", "duration", "feed_programmed", "feed_mean", "spindle_speed", "tool",
                "mrr_max", "removed_volume", "force_max", "torque_max", "spindle_power_max", "cutting_power_max",
                "deflection_max", "axial_depth_max", "radial_depth_max", "in_cut_fraction", "chatter_indicator",
                "chatter_growth", "sle_mean", "sle_max", "volume_ratio", "plunge")


@dataclass(frozen=True)
class ProcessReport:
    """The files written and the headline figures (SI)."""
    html: Path
    json: Path
    blocks_parquet: Path
    blocks_csv: Path
    stl: Path | None
    machining_time: float          # s: from the first program line to the tool's last motion
    cutting_time: float            # s: in material (axial_depth > 0)
    max_force: float               # N: resultant
    max_torque: float              # N.m
    max_power: float               # W: total spindle power (cutting power without a power instance)
    max_deflection: float          # m: resultant tool-tip displacement
    removed_volume: float          # m3: the Workpiece's removed_volume at the end of the run
    removed_volume_zmap: float | None   # m3: stock - final Z-map volume
    blocks: int
    chatter_blocks: int
    warnings: tuple[str, ...]
    wall_time: float               # s: writing this report
    timings: dict[str, float] = field(default_factory=dict)


def _f(x: Any, digits: int = 4) -> str:
    if x is None:
        return "n/a"
    if isinstance(x, (bool, np.bool_)):
        return "yes" if x else ""
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    x = float(x)
    if math.isnan(x):
        return "n/a"
    return f"{x:.{digits}g}"


def _q(value: float | None, column: str, digits: int = 4) -> str:
    """A headline value in the display unit of the block table's column of the same quantity."""
    c = BY_NAME[column]
    if value is None or not math.isfinite(value):
        return "n/a"
    return f"{value * c.factor:.{digits}g} {c.display_unit}"


def _max(values: np.ndarray) -> float:
    finite = values[np.isfinite(values)]
    return float(np.abs(finite).max()) if finite.size else math.nan


def _machining_time(signals: Signals) -> float:
    """From the first sample of a program line to the tool's last motion (or the program's end)."""
    line = np.nan_to_num(signals[f"{INTERPOLATOR}.line_number"], nan=0.0)
    started = np.flatnonzero(line > 0)
    if started.size == 0:
        return 0.0
    t = signals.time
    if signals.has(f"{INTERPOLATOR}.finished"):
        done = np.flatnonzero(np.nan_to_num(signals[f"{INTERPOLATOR}.finished"]) > 0.5)
        if done.size:
            return float(t[done[0]] - t[started[0]])
    xyz = np.column_stack([np.nan_to_num(signals[f"{INTERPOLATOR}.{a}"]) for a in "xyz"])
    moved = np.flatnonzero(np.any(xyz != xyz[-1], axis=1))
    end = t[min(moved[-1] + 1, t.size - 1)] if moved.size else t[started[0]]
    return float(end - t[started[0]])


def _sample_weights(t: np.ndarray) -> np.ndarray:
    """Each sample's share of time: to the next sample (the last: the median spacing)."""
    if t.size < 2:
        return np.zeros(t.size)
    dt = np.diff(t)
    return np.r_[dt, np.median(dt)]


# m3: a rapid move that removes less than this (a thousandth of a mm3) is rounding at a surface, not a collision
RAPID_CUT_TOLERANCE = 1e-12


def rapid_samples(signals: Signals, feeds: Mapping[int, float]) -> np.ndarray:
    """The samples in a rapid move: ``interp.rapid`` when recorded, else those of a line whose programmed feed is 0
    (a line of rapids; ``feeds``: line -> programmed feed)."""
    if signals.has(f"{INTERPOLATOR}.rapid"):
        return np.nan_to_num(signals[f"{INTERPOLATOR}.rapid"]) > 0.5
    line = np.nan_to_num(signals[f"{INTERPOLATOR}.line_number"]).astype(np.int64)
    lines, where = np.unique(line, return_inverse=True)
    return np.array([feeds.get(int(v), 1.0) == 0.0 for v in lines], dtype=bool)[where.ravel()]


def rapid_cuts(signals: Signals, spans: Spans, table: pd.DataFrame, feeds: Mapping[int, float]) -> list[str]:
    """A warning for every block whose rapid move (G0) removes material: on the machine a collision. The program
    checks before the run cannot see it (what a rapid passes through depends on what earlier blocks removed); the
    Workpiece does: the volume it removes between two samples of the block that are both in a rapid move
    (:func:`rapid_samples`)."""
    if not signals.has(f"{WORKPIECE}.removed_volume") or signals.n < 2:
        return []
    rapid = rapid_samples(signals, feeds)
    removed = np.r_[0.0, np.diff(np.nan_to_num(signals[f"{WORKPIECE}.removed_volume"]))]
    removed[~(rapid & np.r_[False, rapid[:-1]])] = 0.0
    found = []
    for b, (a, c) in enumerate(zip(spans.starts, spans.stops)):
        inside = removed[a + 1:c]  # from the block's first sample on: what led to it belongs to the block before
        volume = float(inside.sum())
        if volume > RAPID_CUT_TOLERANCE:
            first = a + 1 + int(np.flatnonzero(inside > 0)[0])
            found.append(f"line {int(spans.lines[b])}: the rapid move (G0) with T{int(table['tool'].iloc[b])} removes "
                         f"{volume * 1e9:.3g} mm3 of material from t = {signals.time[first]:.4f} s: on the "
                         "machine a collision (feed into the material with G1)")
    return found


def _img(png: bytes, title: str, caption: str = "") -> str:
    data = base64.b64encode(png).decode("ascii")
    return (f"<h3>{html.escape(title)}</h3><img alt='{html.escape(title)}' src='data:image/png;base64,{data}'>"
            + (f"<p class='note'>{html.escape(caption)}</p>" if caption else ""))


def _html_table(header: Sequence[str], rows: Sequence[Sequence[str]]) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in rows)
    return f"<div class='scroll'><table><tr>{head}</tr>{body}</table></div>"


STYLE = """*{box-sizing:border-box}
body{font-family:sans-serif;margin:2em;max-width:1300px;color:#222;overflow-wrap:break-word}
.scroll{max-width:100%;overflow-x:auto;margin:0.5em 0 1em 0}
table{border-collapse:collapse;font-size:0.8em}
td,th{border:1px solid #bbb;padding:2px 5px;text-align:right;vertical-align:top}
th{background:#eee;text-align:center} .note{font-size:0.85em;color:#555}
img{max-width:100%;height:auto;border:1px solid #ddd}
tr.chatter td{background:#fde2e2}
.summary{background:#f4f8ff;padding:0.6em 1em;border-left:4px solid #4a7bd0;max-width:100%}
.summary td{text-align:left;border:none;padding:1px 8px;font-size:1.1em}
.warn{background:#fff6e0;border-left:4px solid #e0a030;padding:0.4em 1em}"""


def _block_rows(table: pd.DataFrame, columns: Sequence[BlockColumn]) -> tuple[list[list[str]], list[bool]]:
    rows, flags = [], []
    data = {c.name: table[c.name].to_numpy() for c in columns}
    for i in range(len(table)):
        rows.append([_f(data[c.name][i]) if c.name in ("block", "line", "tool") or c.unit == "bool"
                     else _f(float(data[c.name][i]) * c.factor) for c in columns])
        flags.append(bool(table["chatter"].iloc[i]))
    return rows, flags


def _blocks_html(table: pd.DataFrame) -> tuple[str, str]:
    columns = [BY_NAME[n] for n in HTML_COLUMNS]
    shown = table
    note = f"All {len(table)} blocks, in program order."
    if len(table) > HTML_BLOCKS:
        load = table["force_max"].fillna(-1.0)
        if not (load > 0).any():
            load = table["cutting_power_max"].fillna(-1.0)
        shown = table.loc[load.sort_values(ascending=False, kind="stable").index[:HTML_BLOCKS]].sort_index()
        note = (f"The {HTML_BLOCKS} most loaded of {len(table)} blocks (largest resultant force), in program order; "
                "blocks.csv and blocks.parquet have all of them.")
    rows, flags = _block_rows(shown, columns)
    head = "".join(f"<th>{html.escape(c.header)}</th>" for c in columns)
    body = "".join(("<tr class='chatter'>" if flag else "<tr>") + "".join(f"<td>{html.escape(v)}</td>" for v in row)
                   + "</tr>" for row, flag in zip(rows, flags))
    return f"<div class='scroll'><table><tr>{head}</tr>{body}</table></div>", note


def write_process_report(part: Part, frame: pd.DataFrame, run_dir: Path, *, zmap_file: Path | None,
                         warnings: Sequence[str] = (), comparisons: Sequence[Any] = ()) -> ProcessReport:
    """Write ``process_report.html``, ``process_report.json``, ``blocks.parquet``, ``blocks.csv`` and (with a
    Z-map file) ``part.stl`` into ``run_dir``. ``frame``: the run's results (SI; ``time`` a column or the index);
    ``warnings``: the run's, listed in the headline; ``comparisons``: ``orchestrator.report.Comparison`` objects
    (their plots are read from ``run_dir``)."""
    t_start = time.perf_counter()
    timings: dict[str, float] = {}
    clock = [t_start]

    def lap(name: str) -> None:
        now = time.perf_counter()
        timings[name] = now - clock[0]
        clock[0] = now

    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    notes = list(dict.fromkeys([*part.warnings, *warnings]))  # the part's checks, then the run's
    signals = Signals(frame)
    t = signals.time
    if not signals.has(f"{INTERPOLATOR}.line_number"):
        notes.append(f"column {INTERPOLATOR}.line_number not recorded: no per-block table")
    spans = block_spans(signals[f"{INTERPOLATOR}.line_number"])
    lines, reason = program_lines(part)
    if reason:
        notes.append(reason)
    table = block_table(signals, spans, lines.feeds, lines.descents)
    notes.extend(rapid_cuts(signals, spans, table, lines.feeds))
    notes.extend(plunge_note(table))
    lap("blocks")

    # each block's tool: its flutes (tooth passing), diameter (analytic volumes), modes (lobes)
    cutting = part.cutting_tools
    block_tool = [part.cutting_tool(int(n)) or cutting[0] for n in table["tool"].to_numpy()] if len(cutting) > 1 \
        else [cutting[0]] * len(table)
    flutes = np.array([int(c.tool.flutes) for c in block_tool], dtype=np.int64)
    in_cut = signals.in_cut()
    dx, dy = signals.deflection()
    for c in cutting:
        if c.tool.flutes < 1:
            notes.append(f"tool T{c.tool.number} has no flute count (tool table): no chatter indicator and no "
                         "surface location error")
    if np.isnan(dx).all():
        notes.append("vibration.tip_displacement_x/y not recorded: no chatter indicator, deflection or surface "
                     "location error")
    else:
        indicator = table["chatter_indicator"].to_numpy(dtype=float, copy=True)
        growth = table["chatter_growth"].to_numpy(dtype=float, copy=True)
        speeds = table["spindle_speed"].to_numpy()
        chattering = np.zeros(len(table), dtype=bool)
        for b, (a, c) in enumerate(zip(spans.starts, spans.stops)):
            if in_cut[a:c].sum() < chatter.MIN_SAMPLES:
                continue
            if flutes[b] < 1:
                continue
            result = chatter.analyse(t[a:c], dx[a:c], dy[a:c], in_cut[a:c], speeds[b], int(flutes[b]))
            indicator[b], growth[b], chattering[b] = result.indicator, result.growth, result.chatter
        table["chatter_indicator"], table["chatter_growth"] = indicator, growth
        table["chatter"] = chattering
    lap("chatter")
    sle_mean, sle_max, _ = surface_location_errors(signals, spans, flutes, part.coarse_step)
    diameters = np.array([c.tool.diameter for c in block_tool], dtype=float)
    analytic, removed_window = analytic_volumes(signals, spans, diameters, part.stock.resolution)
    if (flutes >= 1).any():
        table["sle_mean"], table["sle_max"] = sle_mean, sle_max
    table["analytic_volume"] = analytic
    with np.errstate(invalid="ignore", divide="ignore"):
        table["volume_ratio"] = removed_window / analytic
    lap("surface")

    parquet, csv = run_dir / "blocks.parquet", run_dir / "blocks.csv"
    atomic_files.write_with(parquet, lambda tmp_parquet: atomic_files.write_with(
        csv, lambda tmp_csv: write_block_table(table, tmp_parquet, tmp_csv)))
    lap("tables")

    # the final Z-map
    grid: ZMapGrid | None = None
    stl_path: Path | None = None
    removed_zmap: float | None = None
    triangles = 0
    if zmap_file is None:
        notes.append("no Z-map file (workpiece.zmap_file): no machined surface, STL or volume check")
    elif not Path(zmap_file).is_file():
        notes.append(f"{zmap_file}: the Z-map file was not written: no machined surface, STL or volume check")
    else:
        try:
            grid = load_zmap(Path(zmap_file), part.program_zero)
        except (OSError, ValueError) as exc:
            notes.append(f"{zmap_file}: not read ({exc})")
    bottom = part.stock.origin[2]
    removed_run = float(signals[f"{WORKPIECE}.removed_volume"][-1]) if signals.n else math.nan
    if grid is not None:
        removed_zmap = part.stock.volume - grid.volume(bottom)
        cells = grid.x.size * grid.y.size
        if cells <= STL_MAX_CELLS:
            stl_path = run_dir / "part.stl"
            surface = grid
            triangles = atomic_files.write_with(stl_path, lambda tmp: write_stl(surface, bottom, tmp))
        else:
            notes.append(f"{zmap_file}: no STL: the Z-map has {cells} cells, more than {STL_MAX_CELLS} (the STL "
                         f"takes 100 bytes a cell: {cells * 1e-4:.0f} MB; a coarser [part.stock] resolution gives one)")
        if math.isfinite(removed_run) and abs(removed_zmap - removed_run) > VOLUME_AGREEMENT * part.stock.volume:
            notes.append(f"removed volume: the run's removed_volume {removed_run * 1e6:.6g} cm3 differs from stock - "
                         f"final Z-map {removed_zmap * 1e6:.6g} cm3 ({zmap_file})")
    lap("zmap")

    # headline
    fx, fy, fz = (signals[f"{FORCE}.F{a}"] for a in "xyz")
    resultant = np.sqrt(np.nan_to_num(fx) ** 2 + np.nan_to_num(fy) ** 2 + np.nan_to_num(fz) ** 2)
    if np.isnan(fx).all():
        resultant = np.full(signals.n, np.nan)
    power = signals.get(f"{POWER}.P_total", f"{POWER}.P_cutting", f"{FORCE}.power")
    deflection = np.hypot(dx, dy)
    report = dict(
        machining_time=_machining_time(signals),
        cutting_time=float(_sample_weights(t)[in_cut].sum()),
        max_force=_max(resultant), max_torque=_max(signals[f"{FORCE}.torque"]), max_power=_max(power),
        max_deflection=_max(deflection), removed_volume=removed_run, removed_volume_zmap=removed_zmap,
        blocks=len(table), chatter_blocks=int(table["chatter"].sum()))
    power_name = next((n for n in (f"{POWER}.P_total", f"{POWER}.P_cutting", f"{FORCE}.power") if signals.has(n)),
                      "power")
    headline = [
        ("machining time", f"{report['machining_time']:.4g} s"),
        ("cutting time (tool in material)", f"{report['cutting_time']:.4g} s"),
        ("largest resultant force", _q(report["max_force"], "force_max")),
        ("largest torque", _q(report["max_torque"], "torque_max")),
        (f"largest power ({power_name})", _q(report["max_power"], "spindle_power_max")),
        ("largest tool deflection", _q(report["max_deflection"], "deflection_max")),
        ("removed volume: run / stock - final Z-map",
         f"{_q(removed_run, 'removed_volume', 7)} / {_q(removed_zmap, 'removed_volume', 7)}"),
        ("blocks / in chatter", f"{len(table)} / {report['chatter_blocks']} (indicator above "
                                f"{chatter.CHATTER_THRESHOLD:g}, not dying out)"),
    ]
    lap("headline")

    # figures
    figures: list[str] = []
    boundaries = t[spans.starts] if len(spans) else np.zeros(0)
    top = table.nlargest(LABELLED_BLOCKS, "force_max") if table["force_max"].notna().any() else table.iloc[:0]
    labels = [(float(r.start_time + 0.5 * r.duration), f"L{int(r.line)}") for r in top.itertuples()]
    series = []
    for name, label, column in ((f"{FORCE}.Fx", "Fx [N]", None), (f"{FORCE}.Fy", "Fy [N]", None),
                                (f"{FORCE}.Fz", "Fz [N]", None), (f"{FORCE}.torque", "torque [N.m]", None),
                                (f"{POWER}.P_total", "P_total [kW]", 1e-3), (f"{POWER}.P_cutting", "P_cutting [kW]",
                                                                              1e-3)):
        if signals.has(name):
            series.append(plots.Series(label, signals[name] * (column or 1.0)))
    if series:
        figures.append(_img(plots.time_series_png(t, series, boundaries, labels, "Force, torque and power"),
                            "Force, torque and power over time",
                            "Grey vertical lines: block starts; the blocks with the largest resultant force are "
                            "named by their program line (L + line). Each curve is the envelope (min and max per "
                            "time bin)."))
    # in the program's coordinates, where the part gives the stock: machine position - program zero
    x_mm, y_mm, z_mm = ((signals[f"{INTERPOLATOR}.{a}"] - zero) * 1e3 for a, zero in zip("xyz", part.program_zero))
    if len(cutting) > 1 and signals.has(f"{INTERPOLATOR}.tool_number"):  # each tool's tip: its own length
        lengths = {c.tool.number: c.length for c in cutting}
        number = np.nan_to_num(signals[f"{INTERPOLATOR}.tool_number"]).astype(np.int64)
        z_mm = z_mm - np.array([lengths.get(int(n), 0.0) for n in number]) * 1e3
    rapid = rapid_samples(signals, lines.feeds)
    if signals.has(f"{INTERPOLATOR}.x") and signals.n > 1:
        box = [(o * 1e3, (o + s) * 1e3) for o, s in zip(part.stock.origin, part.stock.size)]
        figures.append(_img(plots.toolpath_png(x_mm, y_mm, z_mm, resultant, rapid, "resultant force [N]",
                                               "Tool path coloured by the resultant force", box),
                            "Tool path: resultant force",
                            "Rapid moves dashed grey; the stock block's edges thin grey; the program's coordinates "
                            "(machine position - program zero), mm."))
        per_sample = spans.per_sample(table["chatter_indicator"].to_numpy(), signals.n)
        figures.append(_img(plots.toolpath_png(x_mm, y_mm, z_mm, per_sample, rapid, "chatter indicator",
                                               "Tool path coloured by the block's chatter indicator", box,
                                               cmap="coolwarm", vmin=0.0, vmax=1.0),
                            "Tool path: chatter indicator",
                            "Grey: rapid moves and blocks without an indicator (too few in-cut tooth periods)."))
    if grid is not None:
        figures.append(_img(plots.zmap_png(grid.x * 1e3, grid.y * 1e3, grid.heights * 1e3,
                                           f"Final Z-map ({grid.x.size} x {grid.y.size} cells of "
                                           f"{grid.dx * 1e3:.3g} x {grid.dy * 1e3:.3g} mm)"),
                            "Machined surface: final Z-map heights",
                            f"Heights and coordinates in mm, the program's; the STL of the part: "
                            f"{stl_path.name if stl_path else ''} "
                            f"({triangles} triangles, mm)."))
    ktc, krc = part.material.coefficients.get("Ktc"), part.material.coefficients.get("Krc")
    for c in cutting:
        if not ((c.modes_x or c.modes_y) and ktc and krc is not None and c.tool.flutes >= 1):
            notes.append(f"no stability lobes of T{c.tool.number}: no modes, or the material no Ktc/Krc, or the tool "
                         f"no flutes")
            continue
        lobes = stability_lobes(tuple(c.modes_x), tuple(c.modes_y), ktc, krc, int(c.tool.flutes))
        mine = np.array([b is c for b in block_tool], dtype=bool) if len(cutting) > 1 else np.ones(len(table), bool)
        cuts = (table["axial_depth_max"].to_numpy() > 0) & mine
        rpm = np.abs(table["spindle_speed"].to_numpy()) * BY_NAME["spindle_speed"].factor
        depth_mm = table["axial_depth_max"].to_numpy()[cuts] * 1e3
        indicators = table["chatter_indicator"].to_numpy()[cuts]
        title = f"Stability lobes of T{c.tool.number} in {part.material.name} (slotting)"
        names = [f"L{line}" for line in table["line"].to_numpy()[cuts]]
        png = plots.lobes_png(lobes, rpm[cuts], depth_mm, indicators, chatter.CHATTER_THRESHOLD, title, names)
        figures.append(_img(png,
                            f"Stability lobes of T{c.tool.number} and its cutting blocks",
                            "Zero-order (Altintas-Budak) limit for full immersion (slotting) from the tool's modes "
                            "and the material's Ktc, Krc; each cutting block of the tool at its spindle speed and "
                            "largest axial depth, coloured by its chatter indicator (hollow: no indicator). A block "
                            "cutting at partial immersion has its own, different limit."))
    lap("figures")

    # comparisons with recordings
    comparison_html = []
    if comparisons:
        rows = []
        for c in comparisons:
            try:
                scale = 1.0 if c.unit == c.display_unit else conversion_factor(c.unit, c.display_unit)
            except ValueError:  # UnitError: shown in the simulated variable's unit
                scale = 1.0
            rows.append((c.simulated, c.recorded, str(c.n_samples), f"{_f(c.rms_error * scale)} {c.display_unit}",
                         f"{_f(100 * c.relative_rms, 3)} %" if c.relative_rms is not None else "n/a",
                         f"{_f(c.max_error * scale)} {c.display_unit}"))
        comparison_html.append("<h2>Comparisons with the recording</h2>" + _html_table(
            ("simulated", "recorded", "samples", "RMS error", "RMS error / RMS recorded", "max |error|"), rows))
        for c in comparisons:
            plot = run_dir / c.plot
            if plot.is_file():
                comparison_html.append(_img(plot.read_bytes(), f"{c.simulated} vs {c.recorded}"))
    blocks_html, blocks_note = _blocks_html(table)
    lap("comparisons")

    title = f"Process report: {part.program.name}"
    warnings_html = ("<div class='warn'><b>Warnings</b><ul>" + "".join(f"<li>{html.escape(n)}</li>" for n in notes)
                     + "</ul></div>") if notes else "<p class='note'>No warnings.</p>"
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
             f"<style>{STYLE}</style></head><body><h1>{html.escape(title)}</h1>",
             f"<p class='note'>Program <code>{html.escape(str(part.program))}</code> ({html.escape(part.dialect)}), "
             f"{_tools_text(cutting)}; material {html.escape(part.material.name)}; stock "
             f"{' x '.join(f'{s * 1e3:.4g}' for s in part.stock.size)} mm, Z-map cell "
             f"{part.stock.resolution * 1e3:.3g} mm; force model {html.escape(part.force_model)}.</p>",
             "<h2>Headline</h2><div class='summary'><table>"
             + "".join(f"<tr><td>{html.escape(k)}</td><td><b>{html.escape(v)}</b></td></tr>" for k, v in headline)
             + "</table></div>", warnings_html, "<h2>Figures</h2>", *figures, *comparison_html,
             f"<h2>Blocks</h2><p class='note'>{html.escape(blocks_note)} Rows in chatter are shaded. Units in the "
             "headers; definitions in docs/process_report.md.</p>", blocks_html, "</body></html>"]
    html_path = run_dir / "process_report.html"
    atomic_files.write_text(html_path, "".join(parts))
    lap("html")
    wall = time.perf_counter() - t_start
    result = ProcessReport(html=html_path, json=run_dir / "process_report.json", blocks_parquet=parquet,
                           blocks_csv=csv, stl=stl_path, warnings=tuple(notes), wall_time=wall, timings=timings,
                           **report)
    doc = {**asdict(result), "units": {"machining_time": "s", "cutting_time": "s", "max_force": "N",
                                       "max_torque": "N.m", "max_power": "W", "max_deflection": "m",
                                       "removed_volume": "m3", "removed_volume_zmap": "m3", "wall_time": "s"},
           "chatter_threshold": chatter.CHATTER_THRESHOLD, "stl_triangles": triangles,
           "comparisons": [asdict(c) for c in comparisons],
           "block_columns": [{"name": c.name, "unit": c.unit, "display_unit": c.display_unit,
                              "description": c.description} for c in COLUMNS]}
    atomic_files.write_text(result.json, json.dumps(jsonable(doc), indent=2))
    return result


def _tools_text(cutting: Sequence[CutTool]) -> str:
    """The cutting tools for the report's first line (HTML)."""
    text = ", ".join(f"T{c.tool.number} {html.escape(c.tool.name)} D {c.tool.diameter * 1e3:.4g} mm, "
                     f"{int(c.tool.flutes)} flutes" for c in cutting)
    return f"tool {text}" if len(cutting) == 1 else f"tools {text}"
