"""``[optimize]`` of a whole-part scenario file: the objective, each tool's limits, the iteration's settings.

The section stands beside ``[part]`` (``milling-twin run`` ignores it) and is optional: without it the optimizer
shortens the cycle at the original run's largest force of each tool. Values are SI numbers or ``{ value, unit }``
as everywhere in a scenario; each mistake is a :class:`ScenarioError` naming the file and the key.

```toml
[optimize]
objective = "time"        # "time": the shortest cycle within the limits (default); "force": the original cycle
                          # time with the lowest peak force
max_iterations = 6        # re-simulations after the original run (default 6)
tolerance = 0.01          # a limit holds when the re-simulation stays within it by this share (default 1 %)
air_moves = "fastest"     # feed moves in air: "fastest" (the largest feed the tool's limits allow) or "keep"
plunge_slope = 0.25       # a line that cuts while descending more steeply (depth per path length) keeps its feed
speed_range = [0.7, 1.3]  # a tool whose blocks chatter: speeds allowed, times the programmed one ([1, 1]: keep S)
stability_margin = 0.25   # ... and the speed chosen stable at 1.25 x its deepest chattering cut
speed_from = "simulated"  # stable means: in the tool's simulated stability map ("simulated", default), or below
                          # the zero-order limit of slotting ("zero-order")
sub_blocks = true         # split a straight line whose engagement changes along it into sub-blocks with their F
sub_block_length = { value = 3, unit = "mm" }   # the shortest sub-block (default: the tool's radius)
[optimize.limits]         # every tool's; [optimize.limits.T2] for tool 2's own (it takes these as defaults)
force = { value = 250, unit = "N" }           # largest resultant force; default: the original run's, per tool
torque = { value = 1.2, unit = "N.m" }        # default: none
power = { value = 5.5, unit = "kW" }          # largest total spindle power (the machine's); default: none
deflection = { value = 25, unit = "um" }      # largest tool-tip deflection; default: none
feed_per_tooth = { value = [0.01, 0.12], unit = "mm" }   # chip formation: [min, max]; default [0, twice the
                          # largest the program gives the tool]
feed = { value = 6000, unit = "mm/min" }      # the machine's largest feed; default the Interpolator's max_feed
```
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from typing import Any

from milling_twin.orchestrator.part.blocks import PLUNGE_SLOPE
from milling_twin.orchestrator.part.spec import _factor, _value_unit, quantity
from milling_twin.orchestrator.toml_access import TomlAccess

__all__ = ["Limits", "OptimizeSpec", "read_optimize", "OBJECTIVES", "AIR_MOVES", "METRICS", "SPEED_FROM"]

OBJECTIVES = ("time", "force")
AIR_MOVES = ("fastest", "keep")
KEYS = ("objective", "max_iterations", "tolerance", "air_moves", "plunge_slope", "speed_range", "stability_margin",
        "speed_from", "sub_blocks", "sub_block_length", "limits")
SPEED_FROM = ("simulated", "zero-order")
LIMIT_KEYS = ("force", "torque", "power", "deflection", "feed_per_tooth", "feed")
# the limits on the process, by the block-table column they bound (SI)
METRICS = {"force": "force_max", "torque": "torque_max", "power": "spindle_power_max",
           "deflection": "deflection_max"}
UNITS = {"force": "N", "torque": "N.m", "power": "W", "deflection": "m", "feed": "m/s"}


@dataclass(frozen=True)
class Limits:
    """One tool's limits (SI); None: not limited (force: the original run's, filled in by the optimizer)."""
    force: float | None = None
    torque: float | None = None
    power: float | None = None
    deflection: float | None = None
    feed_per_tooth_min: float = 0.0
    feed_per_tooth_max: float | None = None   # None: twice the program's largest for the tool
    feed: float | None = None                 # None: the Interpolator's max_feed

    def process(self) -> dict[str, float]:
        """The limits on the process (force, torque, power, deflection) that are set, by name."""
        return {name: getattr(self, name) for name in METRICS if getattr(self, name) is not None}


@dataclass(frozen=True)
class OptimizeSpec:
    objective: str = "time"
    max_iterations: int = 6
    tolerance: float = 0.01
    air_moves: str = "fastest"
    plunge_slope: float = PLUNGE_SLOPE  # descent per path length (0.25: 14 deg) from which a cutting line keeps feed
    speed_range: tuple[float, float] = (0.7, 1.3)   # a chattering tool's speeds allowed, x the programmed speed
    stability_margin: float = 0.25  # the chosen speed's stability limit: at least (1 + this) x the deepest cut
    speed_from: str = "simulated"   # stable in the tool's simulated map, or by the zero-order limit
    sub_blocks: bool = True         # split straight lines whose engagement changes along them
    sub_block_length: float | None = None   # m: the shortest sub-block; None: the tool's radius
    limits: Limits = field(default_factory=Limits)            # every tool's
    tool_limits: dict[int, Limits] = field(default_factory=dict)  # a tool's own (the others taken from `limits`)

    def for_tool(self, tool: int) -> Limits:
        return self.tool_limits.get(tool, self.limits)


def _limits(ctx: TomlAccess, table: Mapping[str, Any], key: str, base: Limits) -> Limits:
    values: dict[str, Any] = {}
    for name in ("force", "torque", "power", "deflection", "feed"):
        if name in table:
            values[name] = quantity(ctx, table, key, name, UNITS[name], positive=True)
    if "feed_per_tooth" in table:
        k = f"{key}.feed_per_tooth"
        raw, given = _value_unit(ctx, k, table["feed_per_tooth"])
        if not (isinstance(raw, list) and len(raw) == 2 and all(
                isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in raw)):
            ctx.fail(k, f"expected [min, max] (or {{ value = [min, max], unit }}), got {table['feed_per_tooth']!r}")
        factor = _factor(ctx, k, given, "m")
        low, high = float(raw[0]) * factor, float(raw[1]) * factor
        if not 0.0 <= low < high:
            ctx.fail(k, f"expected 0 <= min < max, got {raw!r}")
        values["feed_per_tooth_min"], values["feed_per_tooth_max"] = low, high
    return replace(base, **values)


def read_optimize(ctx: TomlAccess, raw: Any) -> OptimizeSpec:
    """The ``[optimize]`` table (None: absent, the defaults)."""
    if raw is None:
        return OptimizeSpec()
    table = ctx.table(raw, "[optimize]", KEYS)
    objective = ctx.string(table, "[optimize]", "objective", "time", OBJECTIVES)
    iterations = ctx.integer(table, "[optimize]", "max_iterations", 6, 1)
    tolerance = ctx.number(table, "[optimize]", "tolerance", 0.01, positive=True)
    if tolerance >= 0.5:
        ctx.fail("[optimize].tolerance", f"expected a share below 0.5 (0.01 is 1 %), got {tolerance!r}")
    air = ctx.string(table, "[optimize]", "air_moves", "fastest", AIR_MOVES)
    plunge = ctx.number(table, "[optimize]", "plunge_slope", PLUNGE_SLOPE, positive=True)
    speed_range = table.get("speed_range", [0.7, 1.3])
    if not (isinstance(speed_range, list) and len(speed_range) == 2 and all(
            isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in speed_range)
            and 0.0 < speed_range[0] <= 1.0 <= speed_range[1]):
        ctx.fail("[optimize].speed_range", f"expected [low, high] shares of the programmed speed with "
                                           f"0 < low <= 1 <= high, got {speed_range!r}")
    margin = ctx.number(table, "[optimize]", "stability_margin", 0.25, minimum=0.0)
    speed_from = ctx.string(table, "[optimize]", "speed_from", "simulated", SPEED_FROM)
    split = table.get("sub_blocks", True)
    if not isinstance(split, bool):
        ctx.fail("[optimize].sub_blocks", f"expected true or false, got {split!r}")
    sub_block_length = quantity(ctx, table, "[optimize]", "sub_block_length", "m", None, positive=True)
    limits_table = table.get("limits", {})
    if not isinstance(limits_table, dict):
        ctx.fail("[optimize.limits]", f"expected a table, got {limits_table!r}")
    tools = {k: v for k, v in limits_table.items() if k.startswith("T") and k[1:].isdigit()}
    for name in limits_table:
        if name not in LIMIT_KEYS and name not in tools:
            ctx.fail(f"[optimize.limits].{name}", f"unknown key {name!r}; known keys: {', '.join(LIMIT_KEYS)} "
                                                  f"and T<n> tables of one tool's own")
    common = _limits(ctx, limits_table, "[optimize.limits]", Limits())
    own = {}
    for name, sub in tools.items():
        key = f"[optimize.limits.{name}]"
        ctx.table(sub, key, LIMIT_KEYS)
        own[int(name[1:])] = _limits(ctx, sub, key, common)
    return OptimizeSpec(objective, iterations, tolerance, air, plunge, (float(speed_range[0]), float(speed_range[1])),
                        margin, speed_from, split, sub_block_length, common, own)
