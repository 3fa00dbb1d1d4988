"""A spindle speed per tool in a stable pocket of its lobes, for a tool whose blocks chatter at the programmed speed.

For each cutting tool with a block in chatter in the original run (the process report's indicator), the zero-order
stability limit of slotting (``models/stability.py``, the tool's modes, the material's Ktc and Krc, its flutes:
the lobes the process report draws) is evaluated over the allowed speeds, ``speed_range`` times the programmed
one. The speed chosen is the one closest to the programmed speed whose limit is at least ``1 + stability_margin``
times the deepest cut of the tool's chattering blocks; when no allowed speed has that, the speed with the highest
limit (and a note). The re-simulation then says whether the blocks still chatter.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import pandas as pd

from milling_twin.models.stability import stability_lobes

__all__ = ["SpeedChoice", "choose_speeds", "SPEED_POINTS"]

SPEED_POINTS = 801      # speeds evaluated over the allowed range


@dataclass(frozen=True)
class SpeedChoice:
    tool: int
    programmed: float        # rpm: the tool's programmed speed (its chattering blocks' mean)
    chosen: float            # rpm
    depth: float             # m: the deepest cut of its chattering blocks
    limit_programmed: float  # m: the zero-order slotting limit at the programmed speed
    limit_chosen: float      # m: at the chosen speed
    note: str = ""

    @property
    def ratio(self) -> float:
        return self.chosen / self.programmed


def _speed(rad_s: float) -> float:
    return abs(rad_s) * 60.0 / (2.0 * math.pi)


def choose_speeds(part, blocks: pd.DataFrame, speed_range: tuple[float, float], margin: float,
                  tool_of: Callable[[int], int] = int) -> dict[int, SpeedChoice]:
    """The speed of each tool whose blocks chatter in ``blocks`` (the original run's table, SI); ``tool_of``: the
    cutting tool of a block's tool number."""
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
        out[number] = SpeedChoice(number, programmed, chosen, depth, at_programmed, float(limits[best]), note)
    return out
