"""Refining a study where an output crosses a threshold: ``[study.refine]`` (docs/studies.md#refining-a-boundary).

A grid finds a boundary (the depth where chatter sets in, say) only to its spacing. After the cases, each group of
cases that differ only in ``variable`` (one group per spindle speed, say) is searched going up in ``variable`` for
the first case whose ``output`` exceeds ``threshold`` and the case below it; that bracket gets one new case at the
crossing interpolated between the two (in log(output) with ``scale = "log"``, which suits a growth), kept at least
a tenth of the bracket from either end so that every round shrinks it. Each round adds one case per bracketed
group, run in parallel like the others; ``rounds`` rounds, or fewer when no bracket is wider than ``tolerance``
(relative to its upper end). The new cases are ordinary cases of the study: rows of its summary (their ``source``
is ``[study.refine] round <n>``), skipped by ``--resume`` when they finished, read by the post-processor with the
rest.

    [study.refine]
    variable = "force.axial_depth"   # the variable searched (one of the cases' variables)
    output = "chip_growth"           # a column the reductions give
    threshold = 1.0                  # the crossing sought (default 1)
    rounds = 3                       # default 3
    scale = "log"                    # "log" (default) or "linear": how output is interpolated
    tolerance = 0.005                # default 0.005: a bracket narrower than this (relative) is not refined
    extend = 1.27                    # optional: a group on one side of the threshold only gets a case beyond it

With ``extend`` (a factor > 1), a group whose cases all finished on one side of the threshold (a speed stable up
to the grid's deepest depth, say) gets, in the same rounds, a case at its largest value times ``extend`` (all
below the threshold) or at its smallest divided by it (all above), until it brackets a crossing, which the next
rounds refine. A group with a failed case is not extended (a failure marks neither side).
"""
from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Callable, NoReturn

import numpy as np
import pandas as pd

from milling_twin.orchestrator.study.cases import case_id
from milling_twin.orchestrator.study.summary import FIRST, LAST

__all__ = ["Bracket", "RefineSpec", "beyond_the_ends", "first_crossing", "read_refine", "refined_values"]

REFINE_KEYS = ("variable", "output", "threshold", "rounds", "scale", "tolerance", "extend")
# the new value stays this share of the bracket away from either end, so that a round always shrinks it
SAFEGUARD = 0.1


@dataclass(frozen=True)
class RefineSpec:
    variable: str
    output: str
    threshold: float = 1.0
    rounds: int = 3
    scale: str = "log"
    tolerance: float = 0.005
    extend: float | None = None  # a factor > 1: groups on one side of the threshold get a case beyond their end
    key: str = "[study.refine]"


@dataclass(frozen=True)
class Bracket:
    """The first crossing going up in the variable: the case below (``low``) and the first above (``high``)."""

    low: float
    high: float
    low_output: float
    high_output: float
    low_case: str  # case id of the case below

    def estimate(self, threshold: float, scale: str) -> float:
        """The crossing interpolated between the two cases, at least SAFEGUARD of the bracket from either end."""
        width = self.high - self.low
        if scale == "log":
            to = (lambda y: math.log(y) if y > 0 else -math.inf)
        else:
            to = (lambda y: y)
        f_low, f_high, f_at = to(self.low_output), to(self.high_output), to(threshold)
        if math.isfinite(f_low) and math.isfinite(f_high) and f_high > f_low:
            x = self.low + (f_at - f_low) / (f_high - f_low) * width
        else:
            x = self.low + 0.5 * width
        return min(max(x, self.low + SAFEGUARD * width), self.high - SAFEGUARD * width)


def first_crossing(x: Sequence[float], y: Sequence[float], threshold: float
                   ) -> tuple[int, int] | None:
    """Indices (below, above) of the first crossing of ``threshold`` going up in ``x`` (``x`` sorted increasing,
    ``y`` > ``threshold`` above it, <= below); None when no case is above or the first one already is."""
    above = np.flatnonzero(np.asarray(y, dtype=float) > threshold)
    if above.size == 0 or above[0] == 0:
        return None
    return int(above[0]) - 1, int(above[0])


def _check_output(summary: pd.DataFrame, spec: RefineSpec, variables: Sequence[str]) -> None:
    if spec.output not in summary.columns:
        given = [str(c) for c in summary.columns if c not in variables and c not in (*FIRST, *LAST)]
        raise KeyError(f"{spec.output!r} is no output of the reductions (they give {', '.join(given) or 'none'})")


def _groups(rows: pd.DataFrame, spec: RefineSpec, variables: Sequence[str]) -> list[pd.DataFrame]:
    """``rows`` by the values of every variable but ``spec.variable``, each sorted by it."""
    others = [v for v in variables if v != spec.variable and v in rows.columns]
    groups = [g for _, g in rows.groupby(others, sort=True, dropna=False)] if others else [rows]
    return [g.sort_values(spec.variable, kind="stable") for g in groups]


def brackets(summary: pd.DataFrame, spec: RefineSpec, variables: Sequence[str]) -> list[Bracket]:
    """The bracket of every group of finished cases (same values of every variable but ``spec.variable``)."""
    _check_output(summary, spec, variables)
    rows = summary[(summary["status"] == "ok") & summary[spec.variable].notna() & summary[spec.output].notna()]
    found = []
    for group in _groups(rows, spec, variables):
        x = group[spec.variable].to_numpy(dtype=float)
        y = group[spec.output].to_numpy(dtype=float)
        crossing = first_crossing(x, y, spec.threshold)
        if crossing is None:
            continue
        i, j = crossing
        found.append(Bracket(float(x[i]), float(x[j]), float(y[i]), float(y[j]), str(group["case_id"].iloc[i])))
    return found


def beyond_the_ends(summary: pd.DataFrame, spec: RefineSpec, variables: Sequence[str]) -> list[tuple[str, float]]:
    """With ``spec.extend``: (case id, value) of the next case of every group whose cases all finished on one side of
    the threshold: its largest value times ``extend`` when every output is at or below it, its smallest divided by
    ``extend`` when every output is above. Groups with a failed case or without a finite output are left alone."""
    if spec.extend is None:
        return []
    _check_output(summary, spec, variables)
    found = []
    for group in _groups(summary[summary[spec.variable].notna()], spec, variables):
        y = group[spec.output].to_numpy(dtype=float)
        if not (group["status"] == "ok").all() or not np.all(np.isfinite(y)):
            continue
        x = group[spec.variable].to_numpy(dtype=float)
        if np.all(y <= spec.threshold):
            found.append((str(group["case_id"].iloc[-1]), float(x[-1]) * spec.extend))
        elif np.all(y > spec.threshold):
            found.append((str(group["case_id"].iloc[0]), float(x[0]) / spec.extend))
    return found


def refined_values(summary: pd.DataFrame, spec: RefineSpec, variables: Sequence[str],
                   values_of: Mapping[str, Mapping[str, Any]], stop_time: float | None
                   ) -> list[tuple[str, dict[str, Any]]]:
    """The next round's cases: (case id, values) for every bracket wider than the tolerance. ``values_of``: each
    known case's values by id (the new case is the case below with the variable at the estimate, SI)."""
    made: list[tuple[str, dict[str, Any]]] = []
    for bracket in brackets(summary, spec, variables):
        if bracket.high - bracket.low <= spec.tolerance * abs(bracket.high):
            continue
        values = {**values_of[bracket.low_case], spec.variable: bracket.estimate(spec.threshold, spec.scale)}
        made.append((case_id(values, stop_time), values))
    for end_case, value in beyond_the_ends(summary, spec, variables):
        values = {**values_of[end_case], spec.variable: value}
        made.append((case_id(values, stop_time), values))
    return made


def read_refine(table: Any, variables: Sequence[str], fail: Callable[[str, str], NoReturn]) -> RefineSpec:
    """``[study.refine]`` checked: every error names the key."""
    key = "[study.refine]"
    if not isinstance(table, dict):
        fail("study.refine", f"expected a table, got {table!r}")
    for name in table:
        if name not in REFINE_KEYS:
            fail(f"{key}.{name}", f"unknown key {name!r}; known keys: {', '.join(REFINE_KEYS)}")
    variable = table.get("variable")
    if variable not in variables:
        fail(f"{key}.variable", f"expected one of the cases' variables ({', '.join(variables)}), got {variable!r}")
    output = table.get("output")
    if not isinstance(output, str) or not output:
        fail(f"{key}.output", f"expected the name of an output the reductions give, got {output!r}")
    threshold = table.get("threshold", 1.0)
    if isinstance(threshold, bool) or not isinstance(threshold, (int, float)) or not math.isfinite(threshold):
        fail(f"{key}.threshold", f"expected a finite number, got {threshold!r}")
    scale = table.get("scale", "log")
    if scale not in ("log", "linear"):
        fail(f"{key}.scale", f"expected \"log\" or \"linear\", got {scale!r}")
    if scale == "log" and threshold <= 0:
        fail(f"{key}.threshold", f"must be > 0 with scale = \"log\", got {threshold!r}")
    rounds = table.get("rounds", 3)
    if isinstance(rounds, bool) or not isinstance(rounds, int) or not 1 <= rounds <= 20:
        fail(f"{key}.rounds", f"expected a whole number from 1 to 20, got {rounds!r}")
    tolerance = table.get("tolerance", 0.005)
    if isinstance(tolerance, bool) or not isinstance(tolerance, (int, float)) or not 0 <= tolerance < 1:
        fail(f"{key}.tolerance", f"expected a number from 0 to below 1, got {tolerance!r}")
    extend = table.get("extend")
    if extend is not None and (isinstance(extend, bool) or not isinstance(extend, (int, float))
                               or not 1 < extend <= 100):
        fail(f"{key}.extend", f"expected a factor above 1 (at most 100), got {extend!r}")
    return RefineSpec(variable, output, float(threshold), rounds, scale, float(tolerance),
                      None if extend is None else float(extend))
