"""Simulated outputs against recorded channels: error figures, report.json and plots.

For each ``[[compare]]`` pair the recorded channel is resampled (linear; booleans
hold) onto the output times that lie inside the recording (and, for a recording
checked by ``[recorded.checks]``, inside its consistent segments after their first
sample: :meth:`~milling_twin.orchestrator.recorded.RecordedData.consistent`), converted
to the unit of the simulated variable, and ``error = simulated - recorded`` gives:

* ``rms_error`` = sqrt(mean(error^2)), ``mean_abs_error`` = mean(|error|),
  ``max_error`` = max(|error|), ``mean_recorded`` = mean(recorded),
  ``relative_rms`` = rms_error / sqrt(mean(recorded^2)) (None if the recording is all 0).

Figures are in the simulated variable's unit in ``report.json`` and in the display
unit (``[[compare]].unit``, else :func:`~milling_twin.models.units.display_unit_of`) in the plot
``compare_<instance>_<variable>.png``: recorded and simulated over time, and the error.
``report.json`` also says what the recording's check found and repaired (``recording_check``).

With ``[alignment]`` the pairs are compared on the recording's own samples instead: the recorded positions are
aligned with the simulated ones (``orchestrator.align.align_results``), each recorded sample is paired with the
simulated moment of the same machining state, and the simulated output is interpolated (linearly) at that moment.
That is how a recording that starts earlier, waits where the program does not (dwells, a feed hold, the operator)
or runs at another feed override is compared with a simulation on its own time axis. The time map is written as
``time_map.csv`` (recorded_time, simulated_time, confidence) and summarised in ``report.json`` (``alignment``);
plots are over recorded time.

Every file is written atomically (``orchestrator.atomic_files``): a full disk leaves no truncated report.json
or PNG and no temporary file, and the error names the file.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import pandas as pd
from matplotlib.figure import Figure  # no pyplot: no global figure state, Agg by default

from milling_twin.orchestrator import atomic_files
from milling_twin.orchestrator.json_values import jsonable
from milling_twin.orchestrator.results import load_results
from milling_twin.orchestrator.scenario import Compare, Scenario
from milling_twin.orchestrator.align import TimeMap, align_results
from milling_twin.models.units import UnitError, conversion_factor, display_unit_of

__all__ = ["Comparison", "Report", "write_report"]

def _factor(from_unit: str, to_unit: str) -> float:
    return 1.0 if from_unit == to_unit else conversion_factor(from_unit, to_unit)


@dataclass(frozen=True)
class Comparison:
    simulated: str
    recorded: str
    unit: str  # of the figures below
    display_unit: str  # of the plot
    n_samples: int
    rms_error: float
    mean_abs_error: float
    max_error: float
    mean_recorded: float
    relative_rms: float | None
    plot: str  # file name in the run folder


@dataclass(frozen=True)
class Report:
    path: Path  # report.json
    comparisons: tuple[Comparison, ...]


def _pairs(scenario: Scenario, pair: Compare, results: pd.DataFrame,
           time_map: TimeMap | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(time of the plot, simulated, recorded in the simulated variable's unit) of one pair: at the output times
    inside the recording, or (``time_map``) at the recorded samples mapped to simulated time."""
    rec = scenario.recorded
    assert rec is not None  # load_scenario guarantees [recorded] when there is a [[compare]]
    factor = _factor(rec.units[pair.recorded], scenario.variable(pair.simulated).unit)
    times = results["time"].to_numpy(dtype=float)
    values = results[str(pair.simulated)].to_numpy(dtype=float)
    if time_map is None:
        inside = (times >= rec.t_start) & (times <= rec.t_end)
        inside[inside] = rec.consistent(times[inside])
        t = times[inside]
        return t, values[inside], np.asarray(rec.at(pair.recorded, t), dtype=float) * factor
    t_rec, t_sim = time_map.recorded_time, time_map.simulated_time
    inside = (t_sim >= times[0]) & (t_sim <= times[-1]) & (t_rec >= rec.t_start) & (t_rec <= rec.t_end)
    inside[inside] = rec.consistent(t_rec[inside])
    t_rec, t_sim = t_rec[inside], t_sim[inside]
    return t_rec, np.interp(t_sim, times, values), np.asarray(rec.at(pair.recorded, t_rec), dtype=float) * factor


def _compare(scenario: Scenario, pair: Compare, results: pd.DataFrame, run_dir: Path,
             time_map: TimeMap | None = None) -> Comparison:
    rec = scenario.recorded
    assert rec is not None
    unit = scenario.variable(pair.simulated).unit
    t, simulated, recorded = _pairs(scenario, pair, results, time_map)
    error = simulated - recorded
    n = int(t.size)
    rms = float(np.sqrt(np.mean(error**2))) if n else math.nan
    rms_recorded = float(np.sqrt(np.mean(recorded**2))) if n else 0.0
    display = pair.display_unit or display_unit_of(unit)
    try:
        scale = _factor(unit, display)
    except UnitError:  # only possible for a default display unit that does not fit
        display, scale = unit, 1.0
    comparison = Comparison(
        simulated=str(pair.simulated), recorded=pair.recorded, unit=unit, display_unit=display,
        n_samples=n, rms_error=rms,
        mean_abs_error=float(np.mean(np.abs(error))) if n else math.nan,
        max_error=float(np.max(np.abs(error))) if n else math.nan,
        mean_recorded=float(np.mean(recorded)) if n else math.nan,
        relative_rms=rms / rms_recorded if rms_recorded > 0 else None,
        plot=f"compare_{pair.simulated.instance}_{pair.simulated.variable}.png",
    )
    cuts = rec.time[[s.start for s in rec.check.segments[1:]]] if rec.check is not None else np.zeros(0)
    _plot(run_dir / comparison.plot, comparison, pair.simulated.variable, t, simulated, recorded, scale,
          scenario.name, cuts, "recorded time, aligned" if time_map is not None else "time")
    return comparison


def _plot(path: Path, c: Comparison, variable: str, t: np.ndarray, simulated: np.ndarray, recorded: np.ndarray,
          s: float, title: str, cuts: np.ndarray, time_label: str = "time") -> None:
    """``s`` scales values from ``c.unit`` to ``c.display_unit``; ``cuts``: where the recording's consistent
    segments start (drawn as faint lines)."""
    fig = Figure(figsize=(10, 6), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True, height_ratios=[3, 1])
    simulated, recorded = simulated * s, recorded * s
    if cuts.size:
        for ax in (top, bottom):
            ax.vlines(cuts, 0, 1, transform=ax.get_xaxis_transform(), color="tab:purple", alpha=0.15,
                      linewidth=0.8, label=f"{cuts.size} segment cuts" if ax is top else None)
    top.plot(t, recorded, label=f"recorded: {c.recorded}", color="tab:gray", linewidth=1.0)
    top.plot(t, simulated, label=f"simulated: {c.simulated}", color="tab:blue", linewidth=1.0)
    top.set_ylabel(f"{variable} [{c.display_unit}]")
    rel = f"{100 * c.relative_rms:.1f} %" if c.relative_rms is not None else "n/a"
    top.set_title(f"{title}: {c.simulated} vs {c.recorded}\nRMS error {c.rms_error * s:.4g} "
                  f"{c.display_unit} ({rel} of RMS recorded), mean |error| "
                  f"{c.mean_abs_error * s:.4g}, max |error| {c.max_error * s:.4g} {c.display_unit}")
    top.legend(loc="best")
    top.grid(True, alpha=0.3)
    bottom.plot(t, simulated - recorded, color="tab:red", linewidth=1.0)
    bottom.axhline(0.0, color="black", linewidth=0.5)
    bottom.set_ylabel(f"error [{c.display_unit}]")
    bottom.set_xlabel(f"{time_label} [s]")
    bottom.grid(True, alpha=0.3)
    atomic_files.write_with(path, lambda tmp: fig.savefig(tmp, dpi=100, format="png"))


def write_report(scenario: Scenario, run_dir: str | Path, results: pd.DataFrame | None = None) -> Report:
    """Compare every ``[[compare]]`` pair of ``scenario`` with the results in ``run_dir``;
    writes report.json and one PNG per pair there."""
    run_dir = Path(run_dir)
    results = load_results(run_dir) if results is None else results
    time_map = _align(scenario, results, run_dir) if scenario.alignment is not None else None
    comparisons = tuple(_compare(scenario, pair, results, run_dir, time_map) for pair in scenario.compare)
    path = run_dir / "report.json"
    doc = {"scenario": scenario.name, "comparisons": [asdict(c) for c in comparisons],
           "recording_check": check_summary(scenario)}
    if time_map is not None:
        doc["alignment"] = {"method": time_map.method, "samples": int(time_map.recorded_time.size),
                            "mean_confidence": float(np.mean(time_map.confidence)), "time_map": "time_map.csv"}
    atomic_files.write_text(path, json.dumps(jsonable(doc), indent=2))
    return Report(path, comparisons)


def _align(scenario: Scenario, results: pd.DataFrame, run_dir: Path) -> TimeMap:
    """The recording aligned with the results by ``[alignment]``; the map written to ``time_map.csv``."""
    alignment, rec = scenario.alignment, scenario.recorded
    assert alignment is not None and rec is not None  # load_scenario checks both
    time_map = align_results(rec, results, [str(r) for r in alignment.simulated], alignment.recorded,
                             alignment.method)
    table = pd.DataFrame({"recorded_time": time_map.recorded_time, "simulated_time": time_map.simulated_time,
                          "confidence": time_map.confidence})
    atomic_files.write_with(run_dir / "time_map.csv", lambda tmp: table.to_csv(tmp, index=False))
    return time_map


def check_summary(scenario: Scenario) -> dict | None:
    """What ``[recorded.checks]`` found and what its policy did (None: the recording was not checked)."""
    check = scenario.recorded.check if scenario.recorded is not None else None
    if check is None:
        return None
    return {"policy": check.policy, "rows": check.n_rows, "problems": check.counts(),
            "segments_used": len(check.segments), "segments_dropped": len(check.dropped_segments),
            "rows_dropped": check.dropped_rows, "summary": check.summary(),
            "problem_rows": [{"row": p.row, "line": p.row + 2, "kind": p.kind, "detail": p.detail}
                             for p in check.problems]}
