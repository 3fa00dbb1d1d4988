"""A spindle speed per tool in a stable pocket, for a tool whose blocks chatter at the programmed speed.

For each cutting tool with a block in chatter in the original run (the process report's indicator), over the
allowed speeds (``speed_range`` times the programmed one) at ``1 + stability_margin`` times the deepest cut of its
chattering blocks:

- with ``simulate`` (``speed_from = "simulated"``, the default): the tool's simulated stability map at that depth
  (``speed_map.py``: the twin's force/vibration loop of the tool, slotting, over 25 speeds, then 9 more around the
  best of them); the speed chosen is the stable one closest to the programmed speed inside a pocket (its
  neighbours stable too), else the closest stable one, else the one with the smallest dynamic chip (and a note);
- else (``"zero-order"``): the zero-order stability limit of slotting (``models/stability.py``, the tool's modes,
  the material's Ktc and Krc, its flutes: the lobes the process report draws); the speed closest to the programmed
  speed whose limit reaches the depth, else the one with the highest limit (and a note).

The zero-order limits at the programmed and the chosen speed are reported either way. The re-simulation of the
whole part then says whether the blocks still chatter.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd

from milling_twin.models.stability import stability_lobes
from milling_twin.orchestrator.part.model import CutTool
from milling_twin.orchestrator.optimize.speed_map import SPEEDS, SpeedMap, least_chatter, merged, pocket_speed

__all__ = ["FINE_SPEEDS", "SpeedChoice", "SpeedSimulation", "choose_speeds", "SPEED_POINTS"]

SPEED_POINTS = 801      # speeds of the zero-order limit evaluated over the allowed range
FINE_SPEEDS = 9         # the simulated map's second round: speeds across two steps of the first around its best
# (tool, speeds in rpm, depth in m, feed per tooth in m, label of the round) -> the simulated map
SpeedSimulation = Callable[[CutTool, np.ndarray, float, float, str], SpeedMap]


@dataclass(frozen=True)
class SpeedChoice:
    tool: int
    programmed: float        # rpm: the tool's programmed speed (its chattering blocks' mean)
    chosen: float            # rpm
    depth: float             # m: the deepest cut of its chattering blocks
    limit_programmed: float  # m: the zero-order slotting limit at the programmed speed
    limit_chosen: float      # m: at the chosen speed
    note: str = ""
    source: str = "zero-order"           # what chose it: "simulated" (the tool's simulated map) or "zero-order"
    chip_programmed: float = math.nan    # the simulated map's dynamic chip over the feed per tooth, programmed speed
    chip_chosen: float = math.nan        # ... at the chosen speed
    study: Path | None = None            # the simulated map's study file (its last round)
    map: SpeedMap | None = None

    @property
    def stable_chosen(self) -> bool | None:
        """Whether the simulated map has the chosen speed stable (None: chosen from the zero-order lobes)."""
        if self.map is None:
            return None
        return dict(zip(self.map.speeds, self.map.stable)).get(self.chosen, False)

    @property
    def ratio(self) -> float:
        return self.chosen / self.programmed


def _speed(rad_s: float) -> float:
    return abs(rad_s) * 60.0 / (2.0 * math.pi)


def choose_speeds(part, blocks: pd.DataFrame, speed_range: tuple[float, float], margin: float,
                  tool_of: Callable[[int], int] = int,
                  simulate: SpeedSimulation | None = None) -> dict[int, SpeedChoice]:
    """The speed of each tool whose blocks chatter in ``blocks`` (the original run's table, SI); ``tool_of``: the
    cutting tool of a block's tool number; ``simulate``: the tool's simulated map (None: the zero-order lobes)."""
    ktc, krc = part.material.coefficients.get("Ktc"), part.material.coefficients.get("Krc")
    out: dict[int, SpeedChoice] = {}
    if not ktc or krc is None:
        return out
    for cut in part.cutting_tools:
        number = cut.tool.number
        mine = np.array([tool_of(int(t)) == number for t in blocks["tool"].to_numpy()], dtype=bool)
        rows = blocks[mine & blocks["chatter"].fillna(False).astype(bool).to_numpy()]
        if rows.empty or not (cut.modes_x or cut.modes_y) or cut.tool.flutes < 1:
            continue
        programmed = round(_speed(float(rows["spindle_speed"].abs().mean())), 6)
        depth = float(rows["axial_depth_max"].max())
        lobes = stability_lobes(tuple(cut.modes_x), tuple(cut.modes_y), ktc, krc, int(cut.tool.flutes))
        speeds = np.linspace(programmed * speed_range[0], programmed * speed_range[1], SPEED_POINTS)
        limits = np.nan_to_num(np.asarray(lobes.limit(speeds), dtype=float), nan=0.0)
        at_programmed = float(np.nan_to_num(lobes.limit(np.array([programmed]))[0], nan=0.0))
        stable = np.flatnonzero(limits >= (1.0 + margin) * depth)
        if stable.size:
            best = int(stable[np.argmin(np.abs(speeds[stable] - programmed))])
            note = ""
        else:
            best = int(np.argmax(limits))
            note = (f"no speed in {speed_range[0]:g}..{speed_range[1]:g} x {programmed:.0f} rpm has a limit "
                    f"{1 + margin:g} x the deepest chattering cut ({depth * 1e3:.3g} mm): the highest limit is "
                    f"{limits[best] * 1e3:.3g} mm at {speeds[best]:.0f} rpm")
        chosen = float(round(speeds[best]))
        choice = SpeedChoice(number, programmed, chosen, depth, at_programmed, float(limits[best]), note)
        if simulate is not None and speed_range != (1.0, 1.0):
            per_rev = cut.tool.flutes * programmed / 60.0
            per_tooth = float(np.nanmax(rows["feed_programmed"].to_numpy(float))) / per_rev
            choice = _simulated_choice(choice, cut, lobes, simulate, speed_range, (1.0 + margin) * depth, per_tooth)
        out[number] = choice
    return out


def _simulated_choice(zoa: SpeedChoice, cut: CutTool, lobes, simulate: SpeedSimulation,
                      speed_range: tuple[float, float], depth: float, per_tooth: float) -> SpeedChoice:
    programmed = zoa.programmed
    grid = np.linspace(programmed * speed_range[0], programmed * speed_range[1], SPEEDS)
    coarse = simulate(cut, np.r_[grid, programmed], depth, per_tooth, "")
    pick = pocket_speed(coarse, programmed)
    focus = pick if pick is not None else least_chatter(coarse)
    step = (grid[-1] - grid[0]) / (SPEEDS - 1) if SPEEDS > 1 else 0.0
    fine = np.clip(np.linspace(focus - step, focus + step, FINE_SPEEDS), grid[0], grid[-1])
    found = merged(coarse, simulate(cut, fine, depth, per_tooth, "_fine"))
    pick = pocket_speed(found, programmed)
    chip = dict(zip(found.speeds, found.chip))
    note = ""
    if pick is None:
        pick = least_chatter(found)
        note = (f"no speed in {speed_range[0]:g}..{speed_range[1]:g} x {programmed:.0f} rpm is stable in the "
                f"simulated map at {depth * 1e3:.3g} mm (the deepest chattering cut with the margin): the least "
                f"chatter is at {pick:.0f} rpm, a dynamic chip of {chip[pick]:.3g} x the feed per tooth")
    limit = float(np.nan_to_num(lobes.limit(np.array([pick]))[0], nan=0.0))
    return SpeedChoice(zoa.tool, programmed, float(round(pick)), zoa.depth, zoa.limit_programmed, limit, note,
                       "simulated", chip.get(float(round(programmed)), math.nan), chip.get(pick, math.nan),
                       found.study, found)
