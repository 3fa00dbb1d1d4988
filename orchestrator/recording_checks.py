"""Physical checks of a recording, and its repair into consistent segments.

Real machine loggers write rows out of order, restart their buffers and splice in rows of another
moment (the UMich runs 02-12: blocks of about ten rows at the home position with the spindle stopped,
between blocks of cutting; 19-226 jumps of up to 136 mm per 0.1 s sample). Nothing may use such a
recording as one time-ordered pass. :func:`check_recording` finds the transitions between two
consecutive rows that no machine within the given limits can make:

* ``time``: the time column goes backwards or stands still;
* ``jump``: an axis moves further than its maximum speed allows in the time between the rows (plus the
  logger's timing jitter and the position's storage resolution);
* ``velocity``: with recorded axis velocities, the displacement disagrees with the trapezoid integral of
  the velocities by more than storage resolution, timing jitter and velocity change allow: two rows
  of different moments that happen to lie close to each other;
* ``rate``: another channel with a physical rate limit (the spindle speed: the drive's largest
  acceleration) changes faster than it can, e.g. the spindle at 0 and at 53 rev/s in rows 0.1 s apart
  while the axes stand still in both.

The transitions cut the recording into segments, each physically consistent. A policy says what is
used (:data:`POLICIES`):

* ``segment``: every segment on its own (a segment shorter than ``min_segment`` rows is dropped and
  counted): alignment, reconstruction and calibration treat each piece separately, nothing is joined
  across a cut;
* ``drop``: one time-ordered pass: starting from the first usable segment, each following segment is
  kept when its first row is reachable from the last kept row within the axis limits in the recorded
  time between them; the other segments' rows are dropped and counted;
* ``reorder``: segments sorted by their line numbers, where the line numbers allow it (every segment's
  range of line numbers disjoint from the others'); otherwise refused with the overlapping segments
  named, since programs that repeat lines (subprograms, layers) cannot be put back in order from them.

Rows are 0-based data rows; messages also give the file line (the header is line 1).
"""
from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

__all__ = ["POLICIES", "CheckLimits", "Problem", "RateLimit", "RecordingCheck", "RepairError", "Segment",
           "check_recording", "quantum_of_significant_digits"]

POLICIES = ("segment", "drop", "reorder")
Policy = Literal["segment", "drop", "reorder"]
ProblemKind = Literal["time", "jump", "velocity", "rate"]


class RepairError(ValueError):
    """A recording cannot be repaired by the policy asked for (the message says why and where)."""


@dataclass(frozen=True)
class CheckLimits:
    """What a row-to-row transition may do. SI units: m/s, s, m.

    ``max_axis_speed``: per axis, the fastest the machine moves (its rapid feed);
    ``timing_jitter``: how far a row's real sampling moment may lie from its nominal one;
    ``resolution``: per axis, the storage step of the positions (0: exact), or ``significant_digits``:
    positions stored with that many significant digits (the step then depends on the value: 1 mm from
    100 mm on with 3 digits, 0.1 mm below)."""

    max_axis_speed: tuple[float, ...]
    timing_jitter: float = 0.05
    resolution: tuple[float, ...] | None = None
    significant_digits: int | None = None
    min_segment: int = 3

    def __post_init__(self) -> None:
        if not self.max_axis_speed or any(not np.isfinite(v) or v <= 0 for v in self.max_axis_speed):
            raise ValueError(f"max_axis_speed must be positive numbers, got {self.max_axis_speed!r}")
        if not np.isfinite(self.timing_jitter) or self.timing_jitter < 0:
            raise ValueError(f"timing_jitter must be a non-negative number of seconds, got {self.timing_jitter!r}")
        if self.resolution is not None and self.significant_digits is not None:
            raise ValueError("give at most one of resolution and significant_digits")
        if self.resolution is not None and len(self.resolution) != len(self.max_axis_speed):
            raise ValueError(f"resolution has {len(self.resolution)} values for {len(self.max_axis_speed)} axes")
        if self.significant_digits is not None and not 1 <= self.significant_digits <= 15:
            raise ValueError(f"significant_digits must be 1..15, got {self.significant_digits!r}")
        if self.min_segment < 1:
            raise ValueError(f"min_segment must be at least 1 row, got {self.min_segment!r}")

    def quantum(self, positions: np.ndarray) -> np.ndarray:
        """Storage step of every position value (rows x axes, m)."""
        if self.significant_digits is not None:
            return quantum_of_significant_digits(positions, self.significant_digits)
        steps = np.zeros(positions.shape[1]) if self.resolution is None else np.asarray(self.resolution, float)
        return np.broadcast_to(steps, positions.shape)


def quantum_of_significant_digits(values: np.ndarray, digits: int) -> np.ndarray:
    """The storage step of values written with ``digits`` significant digits (SI: the step of 0.150 m with
    3 digits is 1 mm)."""
    magnitude = np.floor(np.log10(np.maximum(np.abs(np.asarray(values, dtype=float)), 1e-12)))
    return 10.0 ** (magnitude - (digits - 1))


@dataclass(frozen=True)
class Problem:
    """A transition no machine within the limits makes, seen at data row ``row`` (from row - 1)."""

    row: int
    kind: ProblemKind
    detail: str


@dataclass(frozen=True)
class Segment:
    """Data rows ``start`` .. ``stop - 1``, physically consistent."""

    start: int
    stop: int

    def __len__(self) -> int:
        return self.stop - self.start

    @property
    def rows(self) -> slice:
        return slice(self.start, self.stop)


@dataclass(frozen=True)
class RecordingCheck:
    """The outcome: problems found, the segments used under ``policy``, and what was dropped."""

    n_rows: int
    policy: Policy
    problems: tuple[Problem, ...]
    segments: tuple[Segment, ...]           # the ones used, in the order they are used
    dropped_segments: tuple[Segment, ...] = ()
    reasons: dict[int, str] = field(default_factory=dict)  # dropped segment start -> why

    @property
    def used_rows(self) -> np.ndarray:
        return np.concatenate([np.arange(s.start, s.stop) for s in self.segments]) if self.segments \
            else np.zeros(0, dtype=int)

    @property
    def dropped_rows(self) -> int:
        return self.n_rows - int(sum(len(s) for s in self.segments))

    @property
    def clean(self) -> bool:
        return not self.problems

    def counts(self) -> dict[str, int]:
        out = {kind: 0 for kind in ("time", "jump", "velocity", "rate")}
        for p in self.problems:
            out[p.kind] += 1
        return out

    def segment_index(self) -> np.ndarray:
        """Per data row: the index of its segment among ``segments``, -1 where dropped."""
        index = np.full(self.n_rows, -1, dtype=int)
        for i, s in enumerate(self.segments):
            index[s.start:s.stop] = i
        return index

    def summary(self, first_line: int = 2) -> list[str]:
        """Lines for a report: what was found (count, where, why) and what the policy did."""
        counts = self.counts()
        lines = [f"{self.n_rows} rows; {len(self.problems)} impossible transitions "
                 f"({counts['jump']} jumps beyond the axis limits, {counts['velocity']} displacements that "
                 f"disagree with the recorded velocities, {counts['rate']} changes beyond a rate limit, "
                 f"{counts['time']} times going backwards)"]
        lines.append(f"policy {self.policy!r}: {len(self.segments)} segments used "
                     f"({int(sum(len(s) for s in self.segments))} rows), {len(self.dropped_segments)} segments "
                     f"dropped ({self.dropped_rows} rows)")
        for p in self.problems[:20]:
            lines.append(f"  row {p.row} (line {p.row + first_line}): {p.kind}: {p.detail}")
        if len(self.problems) > 20:
            lines.append(f"  ... and {len(self.problems) - 20} more")
        return lines


@dataclass(frozen=True)
class RateLimit:
    """A channel that cannot change faster than ``max_rate`` (its SI unit per second), e.g. the spindle
    speed (rad/s, its largest acceleration in rad/s2); ``resolution`` / ``significant_digits`` as for the
    positions."""

    name: str
    values: np.ndarray
    max_rate: float
    resolution: float = 0.0
    significant_digits: int | None = None

    def quantum(self) -> np.ndarray:
        if self.significant_digits is not None:
            return quantum_of_significant_digits(self.values, self.significant_digits)
        return np.full(self.values.shape, self.resolution)


def _rate_problems(rates: Sequence[RateLimit], time: np.ndarray, jitter: float, flagged: set[int]) -> list[Problem]:
    problems = []
    dt = np.maximum(np.diff(time), 0.0)
    for limit in rates:
        values = np.asarray(limit.values, dtype=float)
        quantum = limit.quantum()
        change = np.abs(np.diff(values))
        allowed = limit.max_rate * (dt + jitter) + 0.5 * (quantum[1:] + quantum[:-1])
        for k in np.flatnonzero(change > allowed):
            row = int(k) + 1
            if row in flagged:
                continue
            flagged.add(row)
            problems.append(Problem(row, "rate", f"{limit.name} changes from {values[k]:.6g} to {values[row]:.6g} "
                                    f"in {time[row] - time[k]:.3g} s (limit {limit.max_rate:.4g} per s)"))
    return problems


def _transitions(positions: np.ndarray, time: np.ndarray, limits: CheckLimits,
                 velocities: np.ndarray | None) -> list[Problem]:
    problems: list[Problem] = []
    dt = np.diff(time)
    quantum = limits.quantum(positions)
    step_quantum = 0.5 * (quantum[1:] + quantum[:-1])  # each stored value is off by at most half its step
    dp = np.diff(positions, axis=0)
    vmax = np.asarray(limits.max_axis_speed, dtype=float)
    reach = vmax[None, :] * (np.maximum(dt, 0.0)[:, None] + limits.timing_jitter) + 2 * step_quantum
    jumps = np.abs(dp) > reach
    if velocities is not None:
        mean_v = 0.5 * (velocities[1:] + velocities[:-1])
        predicted = mean_v * np.maximum(dt, 0.0)[:, None]
        allowed = (2 * step_quantum + 0.5 * np.abs(np.diff(velocities, axis=0)) * dt[:, None]
                   + limits.timing_jitter * np.abs(mean_v) + 1e-9)
        mismatch = np.abs(dp - predicted) > allowed
    else:
        mismatch = np.zeros_like(jumps)
    for k in range(len(dt)):
        row = k + 1
        if dt[k] <= 0:
            problems.append(Problem(row, "time", f"time {time[row]:.6g} s follows {time[k]:.6g} s"))
        elif jumps[k].any():
            a = int(np.argmax(np.abs(dp[k]) - reach[k]))
            problems.append(Problem(row, "jump", f"axis {a} moves {dp[k, a] * 1e3:.4g} mm in {dt[k]:.3g} s "
                                    f"({abs(dp[k, a]) / dt[k] * 1e3:.4g} mm/s; limit "
                                    f"{vmax[a] * 1e3:.4g} mm/s)"))
        elif mismatch[k].any():
            a = int(np.argmax(np.abs(dp[k] - predicted[k]) - allowed[k]))
            problems.append(Problem(row, "velocity", f"axis {a} moves {dp[k, a] * 1e3:.4g} mm, its recorded "
                                    f"velocities {predicted[k, a] * 1e3:.4g} mm"))
    return problems


def _pieces(n: int, problems: Sequence[Problem]) -> list[Segment]:
    cuts = [0] + sorted({p.row for p in problems}) + [n]
    return [Segment(a, b) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]


def _reachable(positions: np.ndarray, time: np.ndarray, limits: CheckLimits, a: int, b: int) -> bool:
    gap = time[b] - time[a]
    if gap <= 0:
        return False
    quantum = limits.quantum(positions[[a, b]])
    reach = np.asarray(limits.max_axis_speed) * (gap + limits.timing_jitter) + quantum.sum(axis=0)
    return bool(np.all(np.abs(positions[b] - positions[a]) <= reach))


def check_recording(positions: np.ndarray, time: np.ndarray, limits: CheckLimits, *, policy: Policy = "segment",
                    velocities: np.ndarray | None = None, lines: np.ndarray | None = None,
                    rates: Sequence[RateLimit] = ()) -> RecordingCheck:
    """Check ``positions`` (rows x axes, m) at ``time`` (s, as recorded), optionally against recorded axis
    ``velocities`` (rows x axes, m/s) and the ``rates`` of other channels, and split them into segments
    under ``policy``. ``lines``: the program line executing at each row (for ``reorder``)."""
    positions = np.asarray(positions, dtype=float)
    time = np.asarray(time, dtype=float)
    if positions.ndim != 2 or positions.shape[0] != time.shape[0]:
        raise ValueError(f"positions must be rows x axes with one row per time, got {positions.shape} and "
                         f"{time.shape}")
    if positions.shape[1] != len(limits.max_axis_speed):
        raise ValueError(f"{positions.shape[1]} position axes but {len(limits.max_axis_speed)} axis speeds")
    if policy not in POLICIES:
        raise ValueError(f"unknown policy {policy!r}; expected one of {', '.join(POLICIES)}")
    if velocities is not None:
        velocities = np.asarray(velocities, dtype=float)
        if velocities.shape != positions.shape:
            raise ValueError(f"velocities {velocities.shape} must have the positions' shape {positions.shape}")
    n = len(time)
    problems = _transitions(positions, time, limits, velocities)
    for rate in rates:
        if np.shape(rate.values) != time.shape:
            raise ValueError(f"rate channel {rate.name!r} has {np.shape(rate.values)} values for {time.shape} times")
    problems += _rate_problems(rates, time, limits.timing_jitter, {p.row for p in problems})
    problems.sort(key=lambda p: p.row)
    pieces = _pieces(n, problems)
    short = [s for s in pieces if len(s) < limits.min_segment]
    reasons = {s.start: f"shorter than min_segment = {limits.min_segment} rows" for s in short}
    usable = [s for s in pieces if len(s) >= limits.min_segment]
    if policy == "segment":
        used = usable
    elif policy == "drop":
        used = []
        for s in usable:
            if not used or _reachable(positions, time, limits, used[-1].stop - 1, s.start):
                used.append(s)
            else:
                reasons[s.start] = (f"not reachable from row {used[-1].stop - 1} within the axis limits in "
                                    f"{time[s.start] - time[used[-1].stop - 1]:.3g} s")
    else:
        used = _reordered(usable, lines)
    dropped = tuple(s for s in pieces if s not in used)
    return RecordingCheck(n, policy, tuple(problems), tuple(used), dropped, reasons)


def _reordered(segments: list[Segment], lines: np.ndarray | None) -> list[Segment]:
    if lines is None:
        raise RepairError("policy 'reorder' needs the program line of every row (a line column)")
    lines = np.asarray(lines)
    ranges = [(float(np.min(lines[s.rows])), float(np.max(lines[s.rows])), s) for s in segments]
    ranges.sort(key=lambda r: (r[0], r[1]))
    for (lo0, hi0, s0), (lo1, hi1, s1) in zip(ranges[:-1], ranges[1:]):
        if lo1 <= hi0:
            raise RepairError(f"policy 'reorder': the line numbers of rows {s0.start}-{s0.stop - 1} "
                              f"({lo0:g}-{hi0:g}) and rows {s1.start}-{s1.stop - 1} ({lo1:g}-{hi1:g}) overlap: "
                              "the program repeats lines, so its rows cannot be put back in order from them; "
                              "use 'segment' or 'drop'")
    return [r[2] for r in ranges]
