"""The per-block table of a whole-part run: one row per program line executed.

A block is a run of consecutive samples with the same ``interp.line_number`` (> 0): a line executed twice (a
subprogram called twice) gives two rows. Statistics over the block's samples ``i0 .. i1-1``:

- ``start_time`` = t[i0], ``end_time`` = t[i1] (the next block's start; the last sample for the last block),
  ``duration`` = end - start;
- means over all the block's samples: feed, spindle speed, MRR, spindle and cutting power; means over its
  in-cut samples (``workpiece.axial_depth > 0``): the forces and the torque (NaN without one); maxima over all
  samples, of the magnitude for signed quantities (``force_x_max`` = max |Fx|);
- ``removed_volume`` = removed_volume[i1-1] - removed_volume[i0-1] (0 before the first sample): the blocks
  add up to the run's last removed_volume exactly;
- ``deflection_max`` = max of the resultant tip displacement sqrt(dx^2 + dy^2);
- ``plunge``: the block removes material and its line descends more steeply than :data:`PLUNGE_SLOPE` (depth per
  length of path, :func:`descent_slopes`): a plunge, a drilling cycle's feed or a steep ramp, whose end cutting
  the force models (flank edges only) leave out.

Values are SI in the table (:func:`block_table`) and the Parquet file (units in each field's metadata, as the
run's chunks: ``b"unit"``, ``b"display_unit"``); the CSV has the display units in its headers
(``"force_max [N]"``). A column whose signal was not recorded (e.g. no power instance) is NaN.
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import pandas as pd

from milling_twin.models.units import conversion_factor
from milling_twin.orchestrator.part.model import FORCE, INTERPOLATOR, POWER, VIBRATION, WORKPIECE, Part

if TYPE_CHECKING:
    from milling_twin.models.interpolator.parser import Move, Program

__all__ = ["BlockColumn", "COLUMNS", "PLUNGE_SLOPE", "ProgramLines", "Signals", "Spans", "block_spans", "block_table",
           "descent_slopes", "feed_lines", "plunge_note", "program_lines", "write_block_table"]

# Descent per length of path (0.25: 14 deg) from which a line that cuts is a plunge or a steep ramp: CuttingForce and
# ForceNet model the flank edges only, so what the end of the tool cuts there is not in their force.
PLUNGE_SLOPE = 0.25


@dataclass(frozen=True)
class BlockColumn:
    name: str
    unit: str           # SI, of the table and the Parquet file
    display_unit: str   # of the CSV and the HTML report
    description: str

    @property
    def factor(self) -> float:
        """SI value * factor = value in the display unit."""
        return 1.0 if self.unit == self.display_unit else conversion_factor(self.unit, self.display_unit)

    @property
    def header(self) -> str:
        return f"{self.name} [{self.display_unit}]" if self.display_unit not in ("", "1", "bool") else self.name


def _c(name: str, unit: str, display: str, description: str) -> BlockColumn:
    return BlockColumn(name, unit, display, description)


COLUMNS: tuple[BlockColumn, ...] = (
    _c("block", "1", "1", "Order of the block in the run (0-based)"),
    _c("line", "1", "1", "Line of the part program (interp.line_number)"),
    _c("start_time", "s", "s", "Time of the block's first sample"),
    _c("end_time", "s", "s", "Time of the next block's first sample (the last sample for the last block)"),
    _c("duration", "s", "s", "end_time - start_time"),
    _c("feed_programmed", "m/s", "mm/min", "Programmed feed F of the line (0: rapid; NaN: no move, or not read)"),
    _c("feed_mean", "m/s", "mm/min", "Mean scheduled path speed (interp.feed)"),
    _c("spindle_speed", "rad/s", "rpm", "Mean commanded spindle speed"),
    _c("tool", "1", "1", "Active tool number at the block's start"),
    _c("mrr_mean", "m3/s", "cm3/min", "Mean material removal rate"),
    _c("mrr_max", "m3/s", "cm3/min", "Largest material removal rate"),
    _c("removed_volume", "m3", "cm3", "Volume removed during the block (difference of workpiece.removed_volume)"),
    _c("force_x_mean", "N", "N", "Mean Fx over the in-cut samples"),
    _c("force_x_max", "N", "N", "Largest |Fx|"),
    _c("force_y_mean", "N", "N", "Mean Fy over the in-cut samples"),
    _c("force_y_max", "N", "N", "Largest |Fy|"),
    _c("force_z_mean", "N", "N", "Mean Fz over the in-cut samples"),
    _c("force_z_max", "N", "N", "Largest |Fz|"),
    _c("force_mean", "N", "N", "Mean resultant force sqrt(Fx^2 + Fy^2 + Fz^2) over the in-cut samples"),
    _c("force_max", "N", "N", "Largest resultant force"),
    _c("torque_mean", "N.m", "N.m", "Mean cutting torque over the in-cut samples"),
    _c("torque_max", "N.m", "N.m", "Largest |torque|"),
    _c("spindle_power_mean", "W", "kW", "Mean total spindle power (power.P_total)"),
    _c("spindle_power_max", "W", "kW", "Largest total spindle power"),
    _c("cutting_power_mean", "W", "kW", "Mean cutting power (power.P_cutting, else force.power)"),
    _c("cutting_power_max", "W", "kW", "Largest cutting power"),
    _c("deflection_max", "m", "um", "Largest resultant tool-tip displacement"),
    _c("axial_depth_max", "m", "mm", "Largest axial depth of cut"),
    _c("radial_depth_max", "m", "mm", "Largest radial depth of cut"),
    _c("in_cut_fraction", "1", "1", "Share of the block's samples with axial_depth > 0"),
    _c("chatter_indicator", "1", "1", "Share of the vibration energy away from the tooth-passing harmonics"),
    _c("chatter_growth", "1/s", "1/s", "Growth rate of the vibration's RMS over successive tooth periods"),
    _c("chatter", "bool", "bool", "chatter_indicator above the threshold"),
    _c("sle_mean", "m", "um", "Mean surface location error (deflection normal to the feed at the finished wall)"),
    _c("sle_max", "m", "um", "Largest |surface location error|"),
    _c("analytic_volume", "m3", "cm3", "Width x length x depth of the steady part of a straight cut at constant depth"),
    _c("volume_ratio", "1", "1", "Volume removed over the same samples as analytic_volume / analytic_volume"),
    _c("plunge", "bool", "bool", "Removes material descending more steeply than PLUNGE_SLOPE: its end cutting is "
                                 "not in the force, torque, cutting power, deflection and chatter"),
)
BY_NAME = {c.name: c for c in COLUMNS}
INT_COLUMNS = ("block", "line", "tool")


class Signals:
    """The frame's columns as float arrays; a column not recorded reads as NaN (``has`` tells)."""

    def __init__(self, frame: pd.DataFrame) -> None:
        self.frame = frame
        if "time" in frame.columns:
            self.time = frame["time"].to_numpy(dtype=float)
        else:
            self.time = frame.index.to_numpy(dtype=float)
        self.n = len(self.time)
        self._cache: dict[str, np.ndarray] = {}

    def has(self, name: str) -> bool:
        return name in self.frame.columns

    def __getitem__(self, name: str) -> np.ndarray:
        if name not in self._cache:
            if name in self.frame.columns:
                self._cache[name] = self.frame[name].to_numpy(dtype=float, na_value=np.nan)
            else:
                self._cache[name] = np.full(self.n, np.nan)
        return self._cache[name]

    def get(self, *names: str) -> np.ndarray:
        """The first recorded of ``names`` (NaN if none is)."""
        for name in names:
            if self.has(name):
                return self[name]
        return self[names[0]]

    def in_cut(self) -> np.ndarray:
        depth = self[f"{WORKPIECE}.axial_depth"]
        return np.nan_to_num(depth, nan=0.0) > 0.0

    def deflection(self) -> tuple[np.ndarray, np.ndarray]:
        return self[f"{VIBRATION}.tip_displacement_x"], self[f"{VIBRATION}.tip_displacement_y"]


@dataclass(frozen=True)
class Spans:
    """The blocks: first sample, one past the last, and the line of each."""
    starts: np.ndarray
    stops: np.ndarray
    lines: np.ndarray

    def __len__(self) -> int:
        return int(self.starts.size)

    def per_sample(self, per_block: np.ndarray, n: int, fill: float = math.nan) -> np.ndarray:
        """A value per block spread over that block's samples, ``fill`` on the ``n`` samples outside every block."""
        out = np.full(n, fill, dtype=float)
        for value, a, c in zip(per_block, self.starts, self.stops):
            out[a:c] = value
        return out


def block_spans(line_number: np.ndarray) -> Spans:
    """Runs of equal line numbers, without line 0 (before the start) and missing values."""
    line = np.nan_to_num(np.asarray(line_number, dtype=float), nan=0.0)
    if line.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        return Spans(empty, empty, empty)
    change = np.flatnonzero(np.diff(line) != 0) + 1
    starts = np.r_[0, change]
    stops = np.r_[change, line.size]
    keep = line[starts] > 0
    return Spans(starts[keep], stops[keep], line[starts[keep]].astype(np.int64))


def feed_lines(program: Program) -> dict[int, list[Move]]:
    """The feed moves of each program line (lines, arcs, NURBS and a cycle's feed moves; not rapids or dwells)."""
    from milling_twin.models.interpolator.parser import MOVE_DWELL, MOVE_RAPID

    out: dict[int, list[Move]] = {}
    for move in program.moves:
        if move.kind not in (MOVE_RAPID, MOVE_DWELL):
            out.setdefault(move.line, []).append(move)
    return out


def descent_slopes(program: Program) -> dict[int, float]:
    """Each feed-move line's steepest descent: how much the tool goes down per length of path (1: a plunge along
    -Z, 0: level or rising; a helical ramp its pitch over its arc length; NURBS blocks 0, not measured)."""
    from milling_twin.models.interpolator.parser import MOVE_ARC, MOVE_LINE
    from milling_twin.models.interpolator.path import ArcShape

    slopes: dict[int, float] = {}
    for line, moves in feed_lines(program).items():
        steepest = 0.0
        for move in moves:
            drop = move.start[2] - move.end[2]
            if drop <= 0.0 or move.kind not in (MOVE_LINE, MOVE_ARC):
                continue
            length = math.dist(move.start, move.end) if move.kind == MOVE_LINE else ArcShape(move).length
            steepest = max(steepest, drop / length if length > 0.0 else 0.0)
        slopes[line] = steepest
    return slopes


@dataclass(frozen=True)
class ProgramLines:
    """What the per-block table takes from the part program, per line, as the Interpolator reads it."""
    feeds: dict[int, float]     # programmed feed (m/s; 0 for a line of rapids only)
    descents: dict[int, float]  # steepest descent of its feed moves per length of path (:func:`descent_slopes`)


def program_lines(part: Part) -> tuple[ProgramLines, str | None]:
    """The part program's :class:`ProgramLines`; empty ones and the reason when it cannot be read."""
    from milling_twin.models.interpolator.parser import MOVE_RAPID
    from milling_twin.orchestrator.part.checks import parse

    try:
        program = parse(part.program, part.dialect, part.tools, part.machine)
    except (OSError, ValueError) as exc:
        return ProgramLines({}, {}), f"{part.program}: programmed feeds not read ({exc})"
    feeds: dict[int, float] = {}
    for move in program.moves:
        feed = 0.0 if move.kind == MOVE_RAPID else float(move.feed)
        feeds[move.line] = max(feeds.get(move.line, 0.0), feed)
    return ProgramLines(feeds, descent_slopes(program)), None


def plunge_note(table: pd.DataFrame) -> list[str]:
    """The report's note on the blocks that ``plunge`` marks (none: no note)."""
    lines = list(dict.fromkeys(int(line) for line in table.loc[table["plunge"].astype(bool), "line"]))
    if not lines:
        return []
    shown = ", ".join(str(line) for line in lines[:12]) + (f" and {len(lines) - 12} more" if len(lines) > 12 else "")
    return [f"plunging or steeply ramping while cutting (descending more than {PLUNGE_SLOPE:g} per length of path), "
            f"line{'s' if len(lines) > 1 else ''} {shown}: the force models have flank edges only, so the end "
            "cutting is not in these blocks' force, torque, cutting power, deflection and chatter (their MRR and "
            "removed volume are the Workpiece's)"]


def _sums(values: np.ndarray, cuts: np.ndarray) -> np.ndarray:
    return np.add.reduceat(values, cuts) if values.size else np.zeros(0)


def block_table(signals: Signals, spans: Spans, feeds: Mapping[int, float] | None = None,
                descents: Mapping[int, float] | None = None) -> pd.DataFrame:
    """The statistics of :data:`COLUMNS` per block, SI: up to ``in_cut_fraction``, and ``plunge`` from ``descents``
    (line -> :func:`descent_slopes`; none: no plunge); the chatter and surface columns are NaN here (the chatter
    indicator and the surface fill them)."""
    n_blocks = len(spans)
    t = signals.time
    out: dict[str, np.ndarray] = {"block": np.arange(n_blocks), "line": spans.lines}
    if n_blocks == 0:
        return pd.DataFrame({c.name: pd.Series(dtype=float) for c in COLUMNS})
    starts, stops = spans.starts, spans.stops
    # reduceat over every block: the samples between blocks (line 0) are left out by cutting at each stop too
    cuts = np.unique(np.r_[starts, stops[stops < signals.n]])
    first = np.searchsorted(cuts, starts)
    count = (stops - starts).astype(float)

    def total(values: np.ndarray) -> np.ndarray:
        return _sums(np.nan_to_num(values, nan=0.0), cuts)[first]

    def mean(values: np.ndarray) -> np.ndarray:
        if np.isnan(values).all():
            return np.full(n_blocks, np.nan)
        return total(values) / count

    def largest(values: np.ndarray) -> np.ndarray:
        if np.isnan(values).all():
            return np.full(n_blocks, np.nan)
        return np.maximum.reduceat(np.nan_to_num(np.abs(values), nan=-np.inf), cuts)[first]

    in_cut = signals.in_cut()
    cut_count = total(in_cut.astype(float))

    def mean_in_cut(values: np.ndarray) -> np.ndarray:
        if np.isnan(values).all():
            return np.full(n_blocks, np.nan)
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(cut_count > 0, total(np.where(in_cut, values, 0.0)) / cut_count, np.nan)

    out["start_time"] = t[starts]
    out["end_time"] = np.where(stops < signals.n, t[np.minimum(stops, signals.n - 1)], t[-1])
    out["duration"] = out["end_time"] - out["start_time"]
    feeds = feeds or {}
    out["feed_programmed"] = np.array([feeds.get(int(line), math.nan) for line in spans.lines])
    out["feed_mean"] = mean(signals[f"{INTERPOLATOR}.feed"])
    out["spindle_speed"] = mean(signals[f"{INTERPOLATOR}.spindle_speed"])
    tool = signals[f"{INTERPOLATOR}.tool_number"]
    out["tool"] = np.nan_to_num(tool[starts], nan=0.0).astype(np.int64)
    mrr = signals[f"{WORKPIECE}.mrr"]
    out["mrr_mean"], out["mrr_max"] = mean(mrr), largest(mrr)
    removed = signals[f"{WORKPIECE}.removed_volume"]
    before = np.where(starts > 0, removed[np.maximum(starts - 1, 0)], 0.0)
    out["removed_volume"] = removed[stops - 1] - before
    fx, fy, fz = (signals[f"{FORCE}.F{a}"] for a in "xyz")
    for axis, values in zip("xyz", (fx, fy, fz)):
        out[f"force_{axis}_mean"], out[f"force_{axis}_max"] = mean_in_cut(values), largest(values)
    resultant = np.sqrt(np.nan_to_num(fx) ** 2 + np.nan_to_num(fy) ** 2 + np.nan_to_num(fz) ** 2)
    if np.isnan(fx).all() and np.isnan(fy).all():
        resultant = np.full(signals.n, np.nan)
    out["force_mean"], out["force_max"] = mean_in_cut(resultant), largest(resultant)
    torque = signals[f"{FORCE}.torque"]
    out["torque_mean"], out["torque_max"] = mean_in_cut(torque), largest(torque)
    spindle = signals[f"{POWER}.P_total"]
    out["spindle_power_mean"], out["spindle_power_max"] = mean(spindle), largest(spindle)
    cutting = signals.get(f"{POWER}.P_cutting", f"{FORCE}.power")
    out["cutting_power_mean"], out["cutting_power_max"] = mean(cutting), largest(cutting)
    dx, dy = signals.deflection()
    out["deflection_max"] = largest(np.hypot(dx, dy))
    out["axial_depth_max"] = largest(signals[f"{WORKPIECE}.axial_depth"])
    out["radial_depth_max"] = largest(signals[f"{WORKPIECE}.radial_depth"])
    out["in_cut_fraction"] = cut_count / count
    descents = descents or {}
    steep = np.array([descents.get(int(line), 0.0) > PLUNGE_SLOPE for line in spans.lines], dtype=bool)
    out["plunge"] = steep & (out["removed_volume"] > 0.0)
    table = pd.DataFrame({c.name: out.get(c.name, np.full(n_blocks, np.nan)) for c in COLUMNS})
    table["chatter"] = False
    return table


def _arrow_table(table: pd.DataFrame) -> object:
    import pyarrow as pa

    fields, arrays = [], []
    for column in COLUMNS:
        values = table[column.name].to_numpy()
        if column.name in INT_COLUMNS:
            kind, array = pa.int32(), pa.array(values.astype(np.int32))
        elif column.unit == "bool":
            kind, array = pa.bool_(), pa.array(values.astype(bool))
        else:
            kind, array = pa.float64(), pa.array(values.astype(float))
        meta = {b"unit": column.unit.encode(), b"display_unit": column.display_unit.encode(),
                b"description": column.description.encode()}
        fields.append(pa.field(column.name, kind, metadata=meta))
        arrays.append(array)
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields))


def display_frame(table: pd.DataFrame, columns: Sequence[BlockColumn] = COLUMNS) -> pd.DataFrame:
    """The table in display units, headers ``name [unit]``."""
    data = {}
    for column in columns:
        values = table[column.name]
        if column.name in INT_COLUMNS or column.unit == "bool":
            data[column.header] = values.to_numpy()
        else:
            data[column.header] = values.to_numpy(dtype=float) * column.factor
    return pd.DataFrame(data)


def write_block_table(table: pd.DataFrame, parquet: Path, csv: Path) -> None:
    """The table as Parquet (SI, units in the field metadata) and CSV (display units in the headers)."""
    import pyarrow.parquet as pq

    pq.write_table(_arrow_table(table), parquet)
    display_frame(table).to_csv(csv, index=False, float_format="%.6g")
