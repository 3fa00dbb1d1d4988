"""The feed of every program line from what the whole-part twin gave in the runs so far (pure functions).

Each run's block table (``orchestrator/part/blocks.py``) is folded into one :class:`LineRun` per program line with
feed moves: its feed factor (programmed feed over the original's), duration, whether it cut, the largest force,
torque, spindle power and deflection over its blocks, chatter. :func:`next_factors` then gives each line the
factor for the next run:

- a line that cuts: for each limit, the feed at which the line's largest value meets it (objective "force": the
  force limit scaled, below). At a fixed engagement the
  mechanistic force is linear in the feed per tooth (``K_c b h + K_e b``), and so are the torque, the cutting
  power and the deflection: from two runs at different feeds the line through both is the model (secant), from one
  the value is taken as proportional to the feed (which overestimates the rise, so the first step stays inside the
  limit; where the secant says no positive feed meets the limit, an edge force or a forced vibration holding the
  value up, the proportional step). The factor is the smallest over the limits, within the feed-per-tooth range
  and the machine's feed, and within ``GROWTH`` times or one ``GROWTH``-th of the last run's (a line whose feed is
  held by acceleration does not react to F; a drop, too, is a step the next run corrects); never below the
  thinnest chip (the per-tooth minimum) unless a limit itself holds the line there;
- a line in air: with ``air_moves = "fastest"`` the largest feed the tool's limits allow (never slower than
  programmed); with ``"keep"`` as programmed;
- a line that chatters where the original did not: no faster than the fastest run in which it did not;
- a line that cuts while it descends more steeply than ``plunge_slope`` (a plunge, a steep ramp): no faster than
  programmed (the force models have flank edges only: a plunge's end cutting is not predicted);
- the spindle stopped, or a tool the part does not cut with: as programmed.

For the objective "force" the force limits of every tool are the original run's largest times one scale, found by
bisection so that the predicted cycle time equals the original's; a line's time is modelled as ``c + d / f`` through
its last two runs (``t f / f_new`` from one).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import pandas as pd

from milling_twin.orchestrator.optimize.spec import METRICS, Limits

__all__ = ["GROWTH", "LineRun", "ToolLimits", "line_runs", "next_factors", "violations", "predicted_time",
           "scale_for_time"]

GROWTH = 4.0          # a line's factor rises (and falls) at most this much from one run to the next
IN_CUT = 1e-9         # in_cut_fraction above which a line cuts


@dataclass(frozen=True)
class LineRun:
    """One program line in one run: its blocks (a line may run more than once) folded together."""
    line: int
    tool: int
    factor: float                 # feed factor of this run (its programmed feed over the original's)
    feed: float                   # m/s: programmed feed in this run
    spindle: float                # rad/s: mean commanded spindle speed
    duration: float               # s
    cuts: bool
    metrics: dict[str, float]     # force, torque, power, deflection: the largest over its blocks (SI)
    chatter: bool


@dataclass(frozen=True)
class ToolLimits:
    """A tool's limits resolved to numbers (SI): the process limits set, the feed range per tooth and the
    machine's feed, and the tool's flutes."""
    process: dict[str, float]
    feed_per_tooth_min: float
    feed_per_tooth_max: float
    feed: float
    flutes: int


def line_runs(blocks: pd.DataFrame, original_feeds: Mapping[int, float], lines: Sequence[int],
              tool_of: Callable[[int], int] = int) -> dict[int, LineRun]:
    """The lines of ``lines`` (those with feed moves) in one run's block table; ``original_feeds``: each line's
    programmed feed in the original program (m/s); ``tool_of``: the cutting tool of a block's tool number (a part
    cut by one tool: that tool, also where the program selects none, T0)."""
    out: dict[int, LineRun] = {}
    wanted = set(lines)
    for line, rows in blocks[blocks["line"].isin(wanted)].groupby("line", sort=True):
        feed = float(np.nanmax(rows["feed_programmed"].to_numpy(float)))
        original = float(original_feeds[int(line)])
        metrics = {name: float(np.nan_to_num(np.nanmax(rows[column].to_numpy(float)), nan=0.0))
                   if rows[column].notna().any() else 0.0 for name, column in METRICS.items()}
        out[int(line)] = LineRun(
            line=int(line), tool=tool_of(int(rows["tool"].iloc[0])), factor=feed / original if original > 0 else 1.0,
            feed=feed, spindle=float(np.nanmean(np.abs(rows["spindle_speed"].to_numpy(float)))),
            duration=float(rows["duration"].sum()),
            cuts=bool((rows["in_cut_fraction"].to_numpy(float) > IN_CUT).any()),
            metrics=metrics, chatter=bool(rows["chatter"].fillna(False).astype(bool).any()))
    return out


def _limited_factor(points: list[tuple[float, float]], limit: float) -> float:
    """The factor at which a value measured at (factor, value) ``points`` (oldest first) reaches ``limit``."""
    f1, m1 = points[-1]
    if m1 <= 0.0:
        return math.inf
    proportional = f1 * limit / m1
    earlier = [(f, m) for f, m in points[:-1] if abs(f - f1) > 1e-3 * f1]
    if not earlier:
        return proportional
    f0, m0 = earlier[-1]
    slope = (m1 - m0) / (f1 - f0)
    if slope <= 1e-3 * m1 / f1:  # the value barely follows the feed (held by acceleration, say): proportional
        return proportional
    secant = (limit - (m1 - slope * f1)) / slope
    # a line whose value stays above the limit at any feed (the secant through zero or below: an edge force, a
    # forced vibration): the proportional step, which never reaches zero
    return secant if secant > 0.0 else proportional


def _feed_bounds(line: LineRun, original_feed: float, limits: ToolLimits) -> tuple[float, float]:
    """The factors of the feed-per-tooth range and the machine's feed (lowest, highest)."""
    per_tooth = limits.flutes * line.spindle / (2.0 * math.pi)  # teeth per second
    highest = limits.feed / original_feed
    lowest = 0.0
    if per_tooth > 0.0:
        highest = min(highest, limits.feed_per_tooth_max * per_tooth / original_feed)
        lowest = limits.feed_per_tooth_min * per_tooth / original_feed
    return lowest, highest


def next_factors(history: Sequence[Mapping[int, LineRun]], original_feeds: Mapping[int, float],
                 limits_of: Callable[[int], ToolLimits | None], air_moves: str,
                 force_scale: float = 1.0, plunges: Collection[int] = ()) -> dict[int, float]:
    """Each line's feed factor for the next run from the runs so far (``history[0]`` the original); ``plunges``:
    lines that descend steeply, which cut no faster than programmed."""
    latest = history[-1]
    factors: dict[int, float] = {}
    for line, run in latest.items():
        limits = limits_of(run.tool)
        if limits is None or run.spindle <= 0.0:
            factors[line] = 1.0
            continue
        lowest, highest = _feed_bounds(run, original_feeds[line], limits)
        cuts = any(h[line].cuts for h in history if line in h)
        if not cuts:
            factors[line] = 1.0 if air_moves == "keep" else max(1.0, highest)
            continue
        def points(name: str) -> list[tuple[float, float]]:
            return [(h[line].factor, h[line].metrics[name]) for h in history if line in h]
        # the factor at the limits themselves, and at the scaled force limit too (the objective "force")
        limit_factor = min((_limited_factor(points(name), limit) for name, limit in limits.process.items()),
                           default=math.inf)
        target = limit_factor
        if "force" in limits.process and force_scale != 1.0:
            target = min(target, _limited_factor(points("force"), limits.process["force"] * force_scale))
        factor = min(target, highest, GROWTH * run.factor)
        factor = max(factor, run.factor / GROWTH)  # and falls at most as much: a step the next run can correct
        if factor < lowest:  # up to the thinnest chip, unless a limit on the process holds the line lower
            factor = min(lowest, limit_factor, highest)
        if line in plunges:  # the end cutting edges are not modelled: a plunge's force is not predicted
            factor = min(factor, 1.0)
        if history[0].get(line) is not None and not history[0][line].chatter:
            calm = [h[line].factor for h in history if line in h and not h[line].chatter]
            if any(h[line].chatter for h in history if line in h):
                factor = min(factor, max(calm))
        factors[line] = max(factor, 1e-3)
    return factors


def violations(runs: Mapping[int, LineRun], limits_of: Callable[[int], ToolLimits | None], tolerance: float,
               original: Mapping[int, LineRun], force_scale: float = 1.0) -> list[str]:
    """What breaks a limit by more than ``tolerance`` in a run (and chatter the original did not have)."""
    found = []
    for line, run in runs.items():
        limits = limits_of(run.tool)
        if limits is None:
            continue
        for name, limit in limits.process.items():
            limit = limit * force_scale if name == "force" else limit
            if run.metrics[name] > limit * (1.0 + tolerance):
                found.append(f"line {line}: {name} {run.metrics[name]:.4g} above its limit {limit:.4g} (SI)")
        if run.chatter and line in original and not original[line].chatter:
            found.append(f"line {line}: chatter, which the original did not have")
    return found


def predicted_time(history: Sequence[Mapping[int, LineRun]], factors: Mapping[int, float]) -> float:
    """The change of the cycle time from the last run's if each line ran at ``factors`` (s; negative: shorter)."""
    change = 0.0
    latest = history[-1]
    for line, run in latest.items():
        f_new = factors.get(line, run.factor)
        points = [(h[line].factor, h[line].duration) for h in history if line in h]
        f1, t1 = points[-1]
        earlier = [(f, t) for f, t in points[:-1] if abs(1.0 / f - 1.0 / f1) > 1e-3 / f1]
        t_new = t1 * f1 / f_new
        if earlier:
            f0, t0 = earlier[-1]
            d = (t1 - t0) / (1.0 / f1 - 1.0 / f0)
            c = t1 - d / f1
            if d >= 0.0 and c >= 0.0:
                t_new = c + d / f_new
        change += t_new - t1
    return change


def scale_for_time(history: Sequence[Mapping[int, LineRun]], original_feeds: Mapping[int, float],
                   limits_of: Callable[[int], ToolLimits | None], air_moves: str, latest_time: float,
                   target_time: float, plunges: Collection[int] = ()) -> float:
    """The force scale whose factors give ``target_time`` as predicted from the runs so far (bisection)."""
    def time_at(scale: float) -> float:
        return latest_time + predicted_time(history, next_factors(history, original_feeds, limits_of, air_moves,
                                                                  scale, plunges))
    low, high = 0.02, 4.0
    if time_at(high) > target_time:
        return high
    if time_at(low) < target_time:
        return low
    for _ in range(50):
        mid = math.sqrt(low * high)
        if time_at(mid) > target_time:
            low = mid
        else:
            high = mid
        if high / low < 1.0 + 1e-4:
            break
    return high


def tool_limits(limits: Limits, flutes: int, original_force: float, largest_per_tooth: float,
                machine_feed: float) -> ToolLimits:
    """One tool's :class:`Limits` resolved: the force default the original run's largest, the per-tooth maximum
    twice the program's largest, the feed the machine's."""
    process = limits.process()
    if limits.force is None and original_force > 0.0:
        process["force"] = original_force
    high = limits.feed_per_tooth_max if limits.feed_per_tooth_max is not None else 2.0 * largest_per_tooth
    return ToolLimits(process, limits.feed_per_tooth_min, high if high > 0 else math.inf,
                      limits.feed if limits.feed is not None else machine_feed, flutes)
