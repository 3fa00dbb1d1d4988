"""The calibration report: one self-contained HTML file (PNG figures embedded as data URIs, inline
style, no scripts, no external references: it opens in a browser with no network) and a Markdown
summary with the same tables (its figures are the PNG files beside it in ``figures/``), plus
``calibration.json`` with the numbers.

Contents: identities of data, scenario, FMUs and models (hashes, versions, instantiation tokens);
the parameter table (initial, estimate, bounds, standard error, 95 % interval, flags); the
correlation matrix and the near-singular directions; per output and data set the fit before and
after calibration and the residuals (plots and statistics); the alignment; the solver trace per
start and the time of every stage; kind-specific figures and tables.

Every file is written atomically (``orchestrator.atomic_files``): figures first, then report.md, report.html and
calibration.json, each complete or unchanged; an earlier report's figures beyond this one's are removed last.
"""
from __future__ import annotations

import base64
import html
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from milling_twin.orchestrator import atomic_files
from milling_twin.orchestrator.json_values import jsonable
from milling_twin.models.units import display_value, format_quantity
from milling_twin.orchestrator.calibrate.plots import correlation_png, fit_png, residual_png, trace_png
from milling_twin.orchestrator.calibrate.result import CalibrationResult, Figure, Table

__all__ = ["write_report", "summary_lines"]


def _f(x: float, digits: int = 4) -> str:
    if x is None or (isinstance(x, float) and math.isnan(x)):
        return "n/a"
    if isinstance(x, float) and math.isinf(x):
        return "inf" if x > 0 else "-inf"
    return f"{x:.{digits}g}"


def _parameter_table(result: CalibrationResult) -> Table:
    rows = []
    for q, st in zip(result.fit.parameters, result.fit.statistics.parameters):
        d = q.display
        rows.append((q.name + (" (nuisance)" if q.nuisance else ""), q.display_unit or "1", _f(d(q.initial)),
                     _f(d(st.estimate), 6), f"[{_f(d(q.lower))}, {_f(d(q.upper))}]", _f(abs(d(st.standard_error)), 3),
                     f"[{_f(d(st.ci_low), 5)}, {_f(d(st.ci_high), 5)}]", "; ".join(st.flags) or "-"))
    return Table("Parameters", ("parameter", "unit", "initial", "estimate", "bounds", "standard error", "95 % CI",
                                "flags"), tuple(rows),
                 f"{result.fit.statistics.n_residuals} residuals, {result.fit.statistics.n_parameters} parameters, "
                 f"residual variance {_f(result.fit.statistics.sigma2)} (weighted; 1 when the weights are the noise "
                 f"levels), t(0.975, {result.fit.statistics.dof}) = {_f(result.fit.statistics.t_quantile)}.")


def _direction_table(result: CalibrationResult) -> Table:
    st = result.fit.statistics
    names = [q.name.split(".", 1)[-1] for q in result.fit.parameters]
    rows = []
    for k, (s, eta) in enumerate(zip(st.singular_values, st.condition_indices)):
        v = st.directions[:, k]
        main = sorted(range(len(v)), key=lambda j: -abs(v[j]))[:3]
        rows.append((str(k + 1), _f(float(s)), _f(float(eta)),
                     ", ".join(f"{v[j]:+.2f} {names[j]}" for j in main if abs(v[j]) > 0.05)))
    return Table("Directions of the parameter space (SVD of the column-normalised Jacobian)",
                 ("direction", "singular value", "condition index", "main components"), tuple(rows),
                 f"A condition index above {_f(result.spec.statistics.condition)} marks a near-singular direction: "
                 "the data determine that combination of parameters poorly.")


def _error_table(result: CalibrationResult) -> Table:
    rows = tuple((e.output, e.dataset + (f" {e.label}" if e.label else ""), str(e.n), e.unit, _f(e.rms_before),
                  _f(e.rms_after), f"{_f(100 * e.relative_before, 3)} %", f"{_f(100 * e.relative_after, 3)} %",
                  _f(e.r2_before, 3), _f(e.r2_after, 3), _f(e.mean_after, 3), _f(e.std_after, 3), _f(e.max_after, 3))
                 for e in result.errors)
    return Table("Errors of the FMU simulation against the recording, before and after calibration",
                 ("output", "data", "samples", "unit", "RMS before", "RMS after", "rel. before", "rel. after",
                  "r2 before", "r2 after", "mean resid. after", "std resid. after", "max |resid.| after"), rows,
                 "Residual = simulated - recorded. 'before': the FMUs with the initial parameters; 'after': the FMUs "
                 "re-run with the written parameter set. Relative = RMS error / RMS recorded.")


def _start_table(result: CalibrationResult) -> Table:
    fit = result.fit
    scale = np.array([q.scale for q in fit.parameters])
    rows = []
    for o in fit.starts + ([fit.refit] if fit.refit else []):
        start = o.x0[: len(scale)] * scale
        chosen = "yes" if o is (fit.refit if fit.refit and fit.refit.x is not None else fit.best) else ""
        stage = "second stage" if o is fit.refit else f"start {o.index}"
        rows.append((stage, ", ".join(_f(float(q.display(v)), 4) for q, v in zip(fit.parameters, start)), o.status,
                     o.message, str(o.iterations), _f(o.objective, 6), f"{o.wall_time:.3f}", chosen))
    return Table("Solver starts", ("start", "start values (display units)", "status", "solver status / cause",
                                   "iterations", "objective", "time [s]", "chosen"), tuple(rows),
                 fit.note or "A failed start is reported with its cause; the run continues with the next start.")


def _identity_table(result: CalibrationResult) -> Table:
    rows = []

    def walk(prefix: str, value: Any) -> None:
        if isinstance(value, dict):
            for k, v in value.items():
                walk(f"{prefix}.{k}" if prefix else str(k), v)
        elif isinstance(value, list):
            for i, v in enumerate(value):
                walk(f"{prefix}[{i}]", v)
        else:
            rows.append((prefix, str(value)))

    walk("", result.identities)
    return Table("Identities (what was fitted to what)", ("item", "value"), tuple(rows))


def _timing_table(result: CalibrationResult) -> Table:
    return Table("Time per stage", ("stage", "wall time [s]"),
                 tuple((k, f"{v:.3f}") for k, v in result.timings.items()))


def _alignment_table(result: CalibrationResult) -> Table | None:
    a = result.alignment
    if a is None:
        return None
    rows = (("method", a.method), ("recorded samples", str(a.recorded_samples)), ("paired", str(a.paired)),
            ("learning pairs", str(a.learning)), ("validation pairs", str(a.validation)),
            ("|simulated - recorded time|: median / p95 / max [s]",
             f"{_f(a.median_shift)} / {_f(a.p95_shift)} / {_f(a.max_shift)}"),
            ("median confidence", _f(a.median_confidence)), ("wall time [s]", f"{a.wall_time:.3f}"))
    return Table("Alignment of recorded samples with simulated times", ("", ""), rows)


def _tables(result: CalibrationResult) -> list[Table]:
    tables = [_parameter_table(result), _direction_table(result), _error_table(result)]
    alignment = _alignment_table(result)
    if alignment is not None:
        tables.append(alignment)
    return tables + list(result.tables) + [_start_table(result), _timing_table(result), _identity_table(result)]


def _figures(result: CalibrationResult) -> list[Figure]:
    figures = []
    groups: dict[tuple[str, str], list] = {}
    for s in result.series:
        groups.setdefault((s.dataset, s.label), []).append(s)
    for (dataset, label), group in groups.items():
        name = f"{dataset} data{' ' + label if label else ''}"
        figures.append(Figure(f"Fit: {name}", fit_png(group),
                              "Recorded (gray), FMUs with the initial parameters (orange) and re-simulated with the "
                              "calibrated parameter set (blue); errors below."))
        figures.append(Figure(f"Residuals: {name}", residual_png(group)))
    names = [q.name for q in result.fit.parameters]
    figures.append(Figure("Correlation matrix of the estimates", correlation_png(names, result.fit.statistics.correlation),
                          "n/a: a parameter without finite variance (not identifiable or no effect)."))
    best = result.fit.best.index
    figures.append(Figure("Solver trace", trace_png(result.fit.starts, best),
                          "Objective per solver iteration for every start; the chosen start is bold."))
    return figures + list(result.figures)


def _html_table(t: Table) -> str:
    head = "".join(f"<th>{html.escape(h)}</th>" for h in t.header)
    body = "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in row) + "</tr>" for row in t.rows)
    note = f"<p class='note'>{html.escape(t.note)}</p>" if t.note else ""
    return f"<h2>{html.escape(t.title)}</h2><div class='scroll'><table><tr>{head}</tr>{body}</table></div>{note}"


def _md_table(t: Table) -> str:
    esc = lambda c: c.replace("|", "\\|").replace("\n", " ")  # noqa: E731
    lines = [f"## {t.title}", "", "| " + " | ".join(esc(h) or " " for h in t.header) + " |",
             "|" + "---|" * len(t.header)]
    lines += ["| " + " | ".join(esc(c) for c in row) + " |" for row in t.rows]
    if t.note:
        lines += ["", t.note]
    return "\n".join(lines)


# Nothing may widen the page beyond the window: the summary's long lines wrap inside its box, long paths
# and hashes in text break anywhere, a table wider than the page scrolls inside its own box.
STYLE = """*{box-sizing:border-box}
body{font-family:sans-serif;margin:2em;max-width:1200px;color:#222;overflow-wrap:break-word}
.scroll{max-width:100%;overflow-x:auto;margin:0.5em 0 1em 0}
table{border-collapse:collapse;font-size:0.85em}
td,th{border:1px solid #bbb;padding:3px 6px;text-align:left;vertical-align:top}
th{background:#eee} .note{font-size:0.85em;color:#555} img{max-width:100%;height:auto;border:1px solid #ddd}
code{overflow-wrap:anywhere}
.summary{background:#f4f8ff;padding:0.6em 1em;border-left:4px solid #4a7bd0;max-width:100%;overflow-x:auto}
.summary pre{margin:0;white-space:pre-wrap;overflow-wrap:anywhere}
.summary pre span{display:block;padding-left:4ch;text-indent:-4ch}"""


def summary_lines(result: CalibrationResult) -> list[str]:
    lines = [f"calibration {result.spec.name} ({result.spec.kind}): {len(result.fit.parameters)} parameters, "
             f"{sum(o.converged for o in result.fit.starts)}/{len(result.fit.starts)} starts converged, "
             f"fit {result.fit.solve_time:.3f} s", f"  derivatives: {result.fit.derivatives}"]
    for q, st in zip(result.fit.parameters, result.fit.statistics.parameters):
        d = q.display
        lines.append(f"  {q.name} = {d(st.estimate):.6g} {q.display_unit} (initial {d(q.initial):.4g}; 95 % CI "
                     f"[{d(st.ci_low):.4g}, {d(st.ci_high):.4g}]){'  ' + '; '.join(st.flags) if st.flags else ''}")
    for e in result.errors:  # in the display unit, as the run summary shows a comparison (kW, not W)
        before, _ = display_value(e.rms_before, e.unit)
        lines.append(f"  {e.output} on {e.dataset}{' ' + e.label if e.label else ''} ({e.n} samples): RMS error "
                     f"{before:.4g} -> {format_quantity(e.rms_after, e.unit)} ({100 * e.relative_before:.2f} % -> "
                     f"{100 * e.relative_after:.2f} % of RMS recorded), r2 {e.r2_before:.3f} -> {e.r2_after:.3f}")
    return lines


def write_report(result: CalibrationResult) -> tuple[Path, Path]:
    """Write report.html, report.md, figures/*.png and calibration.json into ``result.out_dir``."""
    out = result.out_dir
    (out / "figures").mkdir(parents=True, exist_ok=True)
    figures = _figures(result)
    tables = _tables(result)
    spec = result.spec
    title = f"Calibration report: {spec.name}"
    summary = summary_lines(result)
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
             f"<style>{STYLE}</style></head><body><h1>{html.escape(title)}</h1>",
             f"<p>{html.escape(spec.description)}</p>" if spec.description else "",
             "<div class='summary'><pre>" + "".join(f"<span>{html.escape(line)}</span>" for line in summary)
             + "</pre></div>",
             f"<p>Parameter set: <code>{html.escape(str(result.parameter_set))}</code>"
             + (f"; published to <code>{html.escape(str(result.published_set))}</code>" if result.published_set else "")
             + (f"; SSP copy <code>{html.escape(str(result.ssv))}</code>" if result.ssv else "") + "</p>"]
    parts += [f"<p class='note'>{html.escape(n)}</p>" for n in result.notes]
    md = [f"# {title}", "", spec.description, "", "```", *summary, "```", "",
          f"Parameter set: `{result.parameter_set}`"
          + (f"; published to `{result.published_set}`" if result.published_set else "")
          + (f"; SSP copy `{result.ssv}`" if result.ssv else ""), ""]
    md += [f"- {n}" for n in result.notes] + [""]
    for t in tables:
        parts.append(_html_table(t))
        md += [_md_table(t), ""]
    parts.append("<h2>Figures</h2>")
    md += ["## Figures", ""]
    for i, fig in enumerate(figures):
        name = f"figures/{i + 1:02d}.png"
        atomic_files.write_bytes(out / name, fig.png)
        data = base64.b64encode(fig.png).decode("ascii")
        parts.append(f"<h3>{html.escape(fig.title)}</h3><img alt='{html.escape(fig.title)}' "
                     f"src='data:image/png;base64,{data}'>"
                     + (f"<p class='note'>{html.escape(fig.caption)}</p>" if fig.caption else ""))
        md += [f"### {fig.title}", "", f"![{fig.title}]({name})", "", fig.caption, ""]
    parts.append("</body></html>")
    html_path, md_path = out / "report.html", out / "report.md"
    atomic_files.write_text(md_path, "\n".join(md) + "\n")
    atomic_files.write_text(html_path, "".join(parts))
    doc = {
        "spec": str(spec.path), "spec_sha256": spec.sha256, "kind": spec.kind, "derivatives": result.fit.derivatives,
        "parameter_set": str(result.parameter_set),
        "published_parameter_set": str(result.published_set) if result.published_set else None,
        "parameters": [{"name": q.name, "unit": q.unit, "initial": q.initial, "lower": q.lower, "upper": q.upper,
                        "estimate": st.estimate, "standard_error": st.standard_error, "ci95": [st.ci_low, st.ci_high],
                        "flags": list(st.flags), "nuisance": q.nuisance}
                       for q, st in zip(result.fit.parameters, result.fit.statistics.parameters)],
        "correlation": result.fit.statistics.correlation, "sigma2": result.fit.statistics.sigma2,
        "errors": [e.__dict__ for e in result.errors],
        "starts": [{"index": o.index, "status": o.status, "message": o.message, "iterations": o.iterations,
                    "objective": o.objective, "wall_time": o.wall_time} for o in result.fit.starts],
        "timings": result.timings, "identities": result.identities, "notes": result.notes,
        "tables": [{"title": t.title, "header": t.header, "rows": t.rows} for t in result.tables],
        "alignment": result.alignment.__dict__ if result.alignment else None,
    }
    atomic_files.write_text(out / "calibration.json", json.dumps(jsonable(doc), indent=2))
    written = {f"{i + 1:02d}.png" for i in range(len(figures))}
    for stale in (out / "figures").glob("*.png"):  # an earlier report's figures beyond this one's
        if stale.name not in written and not stale.name.startswith("."):
            stale.unlink()
    result.report_html, result.report_md = html_path, md_path
    return html_path, md_path
