"""What a calibration produced, whatever its kind: the input of the report and of the summary."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from milling_twin.orchestrator.calibrate.fit import FitOutcome
from milling_twin.orchestrator.calibrate.pairing import AlignmentSummary
from milling_twin.orchestrator.calibrate.spec import CalibrationSpec

__all__ = ["CalibrationResult", "ErrorRow", "Figure", "Series", "Table", "error_row"]


@dataclass(frozen=True)
class Series:
    """One output on one data set: recorded, and simulated before and after calibration (SI)."""

    output: str  # "power.P_total"
    recorded_channel: str
    dataset: str  # "learning" or "validation"
    time: np.ndarray  # recorded time, s
    recorded: np.ndarray
    before: np.ndarray  # FMU run with the initial parameters
    after: np.ndarray  # FMU re-simulation with the calibrated parameter set
    unit: str
    display_unit: str
    display_factor: float
    label: str = ""  # e.g. the feed of a slot-milling recording
    x_label: str = "recorded time [s]"


@dataclass(frozen=True)
class ErrorRow:
    output: str
    dataset: str
    label: str
    n: int
    unit: str  # display unit of the figures below
    rms_before: float
    rms_after: float
    relative_before: float  # RMS error / RMS recorded
    relative_after: float
    r2_before: float
    r2_after: float
    mean_after: float  # mean residual (simulated - recorded)
    std_after: float
    max_after: float


def _r2(recorded: np.ndarray, simulated: np.ndarray) -> float:
    total = float(np.sum((recorded - recorded.mean()) ** 2))
    return 1.0 - float(np.sum((simulated - recorded) ** 2)) / total if total > 0 else math.nan


def error_row(series: Series) -> ErrorRow:
    s = series.display_factor
    rec, before, after = series.recorded * s, series.before * s, series.after * s
    rms_rec = float(np.sqrt(np.mean(rec ** 2))) if rec.size else math.nan
    e0, e1 = before - rec, after - rec
    rms0, rms1 = float(np.sqrt(np.mean(e0 ** 2))), float(np.sqrt(np.mean(e1 ** 2)))
    return ErrorRow(series.output, series.dataset, series.label, int(rec.size), series.display_unit, rms0, rms1,
                    rms0 / rms_rec if rms_rec > 0 else math.nan, rms1 / rms_rec if rms_rec > 0 else math.nan,
                    _r2(rec, before), _r2(rec, after), float(e1.mean()), float(e1.std()), float(np.abs(e1).max()))


@dataclass(frozen=True)
class Figure:
    title: str
    png: bytes
    caption: str = ""


@dataclass(frozen=True)
class Table:
    title: str
    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    note: str = ""


@dataclass
class CalibrationResult:
    spec: CalibrationSpec
    fit: FitOutcome
    series: list[Series]
    errors: list[ErrorRow]
    identities: dict[str, Any]
    timings: dict[str, float]
    out_dir: Path
    parameter_set: Path  # the set as written, in out_dir
    ssv: Path | None
    alignment: AlignmentSummary | None = None
    notes: list[str] = field(default_factory=list)
    figures: list[Figure] = field(default_factory=list)  # kind-specific, rendered after the generic ones
    tables: list[Table] = field(default_factory=list)
    report_html: Path | None = None
    report_md: Path | None = None
    extra: dict[str, Any] = field(default_factory=dict)  # kind-specific results for scripts (benchmarks)
    published_set: Path | None = None  # the copy written to calibrate(..., write_set=...), if any
