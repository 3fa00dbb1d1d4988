"""What a study keeps of each case: reductions of a finished run to a few named numbers (the summary's outputs).

The shape (stable; the stability map and others plug into it):

- :class:`CaseRun`: one case as it ran on a worker: ``case_id`` (stable hash of its values), ``values`` (the case's
  ``{"instance.variable": value}`` as the study gave them), ``scenario`` (the :class:`Scenario` as run, values
  applied), ``run_dir`` (its run folder: Parquet chunks, run.json), ``status`` (the run's status: "completed",
  "interrupted", "terminated: ...") and ``run`` (the master's :class:`RunResult`). ``case.results`` is the run's
  rows as a DataFrame (SI, column "time" then "instance.variable"), loaded from ``run_dir`` on first use and kept.
- ``Reduction = Callable[..., dict[str, float]]``: called as ``reduction(case, **options)`` where ``options`` are
  the other keys of the study's ``[[study.reduce]]`` table (none for most); returns output name -> value (the
  summary's columns; NaN when the value does not exist for this case, e.g. no row where a condition holds).
- ``REDUCTIONS``: name -> Reduction, the entries a study names with ``[[study.reduce]] kind = "<name>"``. Add one
  with ``@register("name")`` in a module of this package listed in :data:`PLUGIN_MODULES` (``get_reduction`` imports
  them when a name is not registered yet, in whichever process reduces: the workers too). A ``kind`` of the form
  ``"package.module:function"`` names any importable function with the Reduction shape.

Built in (``kind``):

- ``"max"``, ``"min"``, ``"mean"``, ``"rms"``: of ``variable`` (a recorded output), over all rows or only those
  where ``where`` (another recorded output) is > 0; output ``name`` (default ``"<kind>_<variable>"``);
- ``"machining_time"``: a whole part's machining time from its process report, else the time the Interpolator
  (``interp``) reports ``finished`` first, else the run's end time; output ``name`` (default ``"machining_time"``);
- ``"process_report"``: a whole part's headline figures (:data:`PROCESS_FIGURES`, or the list ``fields``);
- ``"rms_error"``: per ``[[compare]]`` pair of the scenario, the recorded-vs-simulated comparison of
  :mod:`milling_twin.orchestrator.report` (its ``rms_error`` and ``relative_rms``); outputs
  ``"rms_error_<simulated>"`` and ``"relative_rms_<simulated>"``.
"""
from __future__ import annotations

import importlib
import json
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

    from milling_twin.orchestrator.master import RunResult
    from milling_twin.orchestrator.scenario import Scenario

__all__ = ["CaseRun", "PLUGIN_MODULES", "Reduction", "REDUCTIONS", "STATISTICS", "get_reduction", "register"]

Reduction = Callable[..., dict[str, float]]  # reduction(case: CaseRun, **options) -> {output name: value}

REDUCTIONS: dict[str, Reduction] = {}

STATISTICS = ("max", "min", "mean", "rms")

PROCESS_REPORT = "process_report.json"  # a whole-part run's report (orchestrator/part/report.py)
PROCESS_FIGURES = ("machining_time", "cutting_time", "max_force", "max_torque", "max_power", "max_deflection",
                   "removed_volume", "removed_volume_zmap", "blocks", "chatter_blocks")

# modules that register reductions, imported on demand by get_reduction (a missing one is skipped)
PLUGIN_MODULES = ("milling_twin.orchestrator.study.stability_map",)


@dataclass(frozen=True)
class CaseRun:
    """One finished case (see the module docstring)."""

    case_id: str
    values: Mapping[str, Any]
    scenario: Scenario
    run_dir: Path
    status: str
    run: RunResult | None = field(default=None, compare=False, repr=False)
    frame: pd.DataFrame | None = field(default=None, compare=False, repr=False)  # the rows, when already loaded

    @cached_property
    def results(self) -> pd.DataFrame:
        """The run's rows (``frame``, else loaded from ``run_dir`` on first use)."""
        if self.frame is not None:
            return self.frame
        from milling_twin.orchestrator.results import load_results

        return load_results(self.run_dir)


def register(name: str) -> Callable[[Reduction], Reduction]:
    """Decorator: ``@register("chatter_growth")`` puts the function into :data:`REDUCTIONS` under ``name``."""
    def add(fn: Reduction) -> Reduction:
        if name in REDUCTIONS and REDUCTIONS[name] is not fn:
            raise ValueError(f"reduction {name!r} is registered already ({REDUCTIONS[name].__module__})")
        REDUCTIONS[name] = fn
        return fn
    return add


def import_plugins() -> None:
    """Import :data:`PLUGIN_MODULES` (which register reductions and post-processors); one that is not installed is
    left out, an error inside one is raised."""
    for module in PLUGIN_MODULES:
        try:
            importlib.import_module(module)
        except ModuleNotFoundError as exc:
            if exc.name != module:
                raise


def get_reduction(kind: str) -> Reduction:
    """The reduction registered as ``kind`` (importing :data:`PLUGIN_MODULES` first if needed), or the function
    ``"package.module:function"``. Raises KeyError naming the known kinds."""
    if kind not in REDUCTIONS:
        import_plugins()
    if kind in REDUCTIONS:
        return REDUCTIONS[kind]
    if ":" in kind:
        module, _, attr = kind.partition(":")
        try:
            fn = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as exc:
            raise KeyError(f"kind = {kind!r}: cannot import {attr!r} from {module!r}: {exc}") from exc
        if not callable(fn):
            raise KeyError(f"kind = {kind!r}: {attr!r} of {module!r} is not a function")
        return fn
    raise KeyError(f"kind = {kind!r}: unknown reduction; known: {', '.join(sorted(REDUCTIONS))} "
                   "(or 'package.module:function')")


def _column(case: CaseRun, variable: str, key: str) -> np.ndarray:
    frame = case.results
    if variable not in frame.columns:
        recorded = ", ".join(c for c in frame.columns if c != "time")
        raise KeyError(f"{key} = {variable!r} is not a recorded output of {case.scenario.name!r} "
                       f"(recorded: {recorded})")
    return frame[variable].to_numpy(dtype=float)


def statistic(case: CaseRun, *, kind: str, variable: str, where: str | None = None,
              name: str | None = None) -> dict[str, float]:
    """max/min/mean/rms of ``variable``, optionally only on the rows where ``where`` > 0."""
    values = _column(case, variable, "variable")
    if where is not None:
        values = values[np.nan_to_num(_column(case, where, "where")) > 0]
    values = values[~np.isnan(values)]
    out = name or f"{kind}_{variable}"
    if values.size == 0:
        return {out: math.nan}
    if kind == "max":
        return {out: float(np.max(values))}
    if kind == "min":
        return {out: float(np.min(values))}
    if kind == "mean":
        return {out: float(np.mean(values))}
    if kind == "rms":
        return {out: float(np.sqrt(np.mean(values * values)))}
    raise ValueError(f"kind = {kind!r}: expected one of {', '.join(STATISTICS)}")


for _kind in STATISTICS:
    REDUCTIONS[_kind] = (lambda k: lambda case, **options: statistic(case, kind=k, **options))(_kind)


@register("machining_time")
def machining_time(case: CaseRun, *, name: str = "machining_time") -> dict[str, float]:
    """A whole part's machining time from its process report (first program line to the tool's last motion or
    the program's end); else the first time the Interpolator reports ``finished``; else the last row's time."""
    report = case.run_dir / PROCESS_REPORT
    if report.is_file():
        return {name: float(json.loads(report.read_text())["machining_time"])}
    frame = case.results
    column = "interp.finished"
    if column in frame.columns:
        done = np.flatnonzero(np.nan_to_num(frame[column].to_numpy(dtype=float)) > 0.5)
        if done.size:
            return {name: float(frame["time"].iloc[int(done[0])])}
    if len(frame):
        return {name: float(frame["time"].iloc[-1])}
    return {name: math.nan}


@register("process_report")
def process_report(case: CaseRun, *, fields: list[str] | None = None) -> dict[str, float]:
    """A whole part's headline figures from its process report (docs/process_report.md), SI: ``fields`` of
    :data:`PROCESS_FIGURES` (default all)."""
    report = case.run_dir / PROCESS_REPORT
    if not report.is_file():
        raise ValueError(f"kind = 'process_report': no {PROCESS_REPORT} in {case.run_dir} (a whole-part scenario "
                         "writes one)")
    doc = json.loads(report.read_text())
    chosen = PROCESS_FIGURES if fields is None else tuple(fields)
    unknown = [f for f in chosen if f not in PROCESS_FIGURES]
    if unknown:
        raise ValueError(f"fields: {unknown[0]!r} is not one of {', '.join(PROCESS_FIGURES)}")
    return {f: math.nan if doc.get(f) is None else float(doc[f]) for f in chosen}


@register("rms_error")
def rms_error(case: CaseRun) -> dict[str, float]:
    """The scenario's ``[[compare]]`` pairs, compared as ``milling-twin run`` does: the run's report.json (written
    by the run), else the comparison made now."""
    if not case.scenario.compare:
        raise ValueError(f"kind = 'rms_error': scenario {case.scenario.path} has no [[compare]] pairs")
    report_file = case.run_dir / "report.json"
    if report_file.is_file():
        comparisons = json.loads(report_file.read_text())["comparisons"]
    else:
        from dataclasses import asdict

        from milling_twin.orchestrator.report import write_report

        comparisons = [asdict(c) for c in write_report(case.scenario, case.run_dir, case.results).comparisons]
    out: dict[str, float] = {}
    for c in comparisons:
        out[f"rms_error_{c['simulated']}"] = math.nan if c["rms_error"] is None else float(c["rms_error"])
        out[f"relative_rms_{c['simulated']}"] = math.nan if c["relative_rms"] is None else float(c["relative_rms"])
    return out
