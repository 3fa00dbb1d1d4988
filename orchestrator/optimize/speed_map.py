"""A chattering tool's simulated stability over the speeds the optimizer may choose: a study of the study layer.

The zero-order lobes are a prediction; the twin's own force/vibration loop is what chatters in the re-simulation.
So for a tool whose blocks chatter, :func:`simulate_speeds` writes a study (``<folder>/T<n>_speeds.toml``) of the
force/vibration loop of ``scenarios/chatter.toml``, built from the part's tool (its flutes, diameter, helix and
modes) and material (the CuttingForce coefficients), slotting (0 to 180 deg, the immersion the zero-order lobes
take) at ``(1 + stability_margin) x`` the deepest chattering cut and at the chattering blocks' feed per tooth, over
:data:`SPEEDS` spindle speeds across the allowed range; it runs on the study layer's workers (dask; ``workers=0``:
in this process) and each case is reduced with the stability map's ``chatter_growth``: stable when the dynamic
chip's growth over the last two quarters of the run is at most 1 (``chip_growth``,
``orchestrator/study/stability_map.py``: the measure whose onsets come closest to the semi-discretization's,
docs/validation.md) and its RMS in the last quarter is at most :data:`LIMIT_CYCLE_CHIP` of the feed per tooth
(chatter that has grown into a limit cycle, the teeth leaving the cut, has a growth of about 1 too, but a dynamic
chip of the order of the chip itself), or when that RMS is below :data:`NOISE_CHIP` of it (the free vibration has
died out: what is left is rounding, whose ratio from window to window says nothing); a case whose vibration grows
beyond the FMUs' range chatters. The study
files stay beside the optimization, so
``milling-twin sweep <folder>/T1_speeds.toml`` runs the same cases again.

:func:`pocket_speed` then picks the speed: the stable speed closest to the programmed one whose neighbours on the
grid are stable too (inside a pocket, not on its edge), else the closest stable one; None when none is (then
:func:`least_chatter`: the speed of the smallest dynamic chip).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from milling_twin.orchestrator import atomic_files
from milling_twin.orchestrator.part.expand import force_tool_parameters, scenario_toml, vibration_parameters
from milling_twin.orchestrator.part.model import CutTool, Part

__all__ = ["LIMIT_CYCLE_CHIP", "NOISE_CHIP", "SPEEDS", "MIN_TEETH", "SpeedMap", "least_chatter", "merged",
           "pocket_speed", "simulate_speeds", "tool_loop_document"]

SPEEDS = 25            # spindle speeds over the allowed range
MIN_TEETH = 60         # tooth periods the slowest case runs at least (the growth compares its last two quarters)
DIVERGED = "out of its allowed range"   # a case whose displacement left the FMUs' range: it chattered
LIMIT_CYCLE_CHIP = 0.1  # a dynamic chip RMS above this share of the feed per tooth: chatter (a limit cycle)
NOISE_CHIP = 1e-3       # ... below this share: the vibration has died out (stable whatever its growth)


@dataclass(frozen=True)
class SpeedMap:
    """One tool's simulated stability at one depth: per speed (rpm) the dynamic chip's growth and stable."""
    tool: int
    depth: float                 # m: the depth simulated ((1 + margin) x the deepest chattering cut)
    speeds: tuple[float, ...]    # rpm
    growth: tuple[float, ...]    # chip_growth of the case (inf: it diverged; NaN: it failed otherwise)
    chip: tuple[float, ...]      # its dynamic chip's RMS in the last quarter over the feed per tooth (inf, NaN: as
                                 # growth)
    study: Path                  # the study file
    summary: Path                # its summary.parquet
    wall_time: float             # s

    @property
    def stable(self) -> tuple[bool, ...]:
        return tuple(bool(c <= NOISE_CHIP or (g <= 1.0 and c <= LIMIT_CYCLE_CHIP))
                     for g, c in zip(self.growth, self.chip))


def tool_loop_document(part: Part, cut: CutTool, speed_rpm: float, depth: float, feed_per_tooth: float,
                       stop_time: float) -> dict[str, Any]:
    """The force/vibration loop of one tool slotting at one speed and depth: a scenario document (SI values)."""
    tool = cut.tool
    omega = speed_rpm * 2.0 * math.pi / 60.0
    force = {**force_tool_parameters(cut), **part.material.coefficients}
    vibration = vibration_parameters(cut)
    feed = feed_per_tooth * tool.flutes * omega / (2.0 * math.pi)
    step = part.fine_step   # the whole-part run's step of the loop in material
    return {
        "scenario": {"name": f"T{tool.number}_loop", "stop_time": stop_time, "output_interval": step,
                     "description": f"T{tool.number}'s force/vibration loop slotting {depth * 1e3:.4g} mm deep "
                                    f"(the feed optimizer's speed check)"},
        "fmus": {
            "force": {"fmu": "CuttingForce", "step_size": step, "parameters": force,
                      "inputs": {"spindle_speed": omega, "feed_velocity_x": feed, "axial_depth": depth,
                                 "entry_angle": 0.0, "exit_angle": math.pi}},
            "vibration": {"fmu": "ToolVibration", "step_size": step, "parameters": vibration}},
        "connections": [{"from": "force.Fx", "to": "vibration.force_x"},
                        {"from": "force.Fy", "to": "vibration.force_y"},
                        {"from": "vibration.tip_displacement_x", "to": "force.displacement_x", "delay": True},
                        {"from": "vibration.tip_displacement_y", "to": "force.displacement_y", "delay": True}],
        "outputs": {"record": ["force.Fx", "force.Fy", "vibration.tip_displacement_x",
                               "vibration.tip_displacement_y"]},
    }


def simulate_speeds(folder: Path, part: Part, cut: CutTool, speeds_rpm: np.ndarray, depth: float,
                    feed_per_tooth: float, fmu_dir: Path, workers: int | None = 0, label: str = "") -> SpeedMap:
    """Write and run the study of ``cut``'s loop at ``depth`` over ``speeds_rpm`` (see the module docstring)."""
    from milling_twin.orchestrator.study.run import sweep
    from milling_twin.orchestrator.study.spec import load_study

    t0 = time.perf_counter()
    number = cut.tool.number
    speeds = sorted({float(round(s)) for s in speeds_rpm})
    slowest = min(speeds)
    stop_time = max(0.2, MIN_TEETH * 60.0 / (slowest * cut.tool.flutes))
    folder.mkdir(parents=True, exist_ok=True)
    base = folder / f"T{number}_loop.toml"
    atomic_files.write_text(base, scenario_toml(tool_loop_document(part, cut, speeds[0], depth, feed_per_tooth,
                                                                   stop_time)))
    name = f"T{number}_speeds{label}"
    study_doc = {"study": {
        "name": name,
        "description": f"T{number} slotting {depth * 1e3:.4g} mm deep over {len(speeds)} spindle speeds: chatter "
                       f"or not (the feed optimizer's choice of speed)",
        "base": base.name,
        "grid": {"force.spindle_speed": {"values": speeds, "unit": "rpm"}},
        "reduce": [{"kind": "chatter_growth"}]}}
    study_file = folder / f"{name}.toml"
    atomic_files.write_text(study_file, tomli_w.dumps(study_doc))
    result = sweep(load_study(study_file, fmu_dir), folder, workers=workers, progress=False)
    summary = result.summary
    by_speed = {round(float(row["force.spindle_speed"]) * 60.0 / (2.0 * math.pi)): row
                for _, row in summary.iterrows()}
    growth, chip = [], []
    for speed in speeds:
        row = by_speed.get(round(speed))
        if row is not None and row.get("status") == "ok":
            growth.append(float(row["chip_growth"]))
            chip.append(float(row["chip_rms"]) / feed_per_tooth)
        elif row is not None and DIVERGED in str(row.get("error", "")):
            growth.append(math.inf)   # the vibration grew beyond the FMUs' range: chatter
            chip.append(math.inf)
        else:
            growth.append(math.nan)   # the case failed otherwise: not counted as stable
            chip.append(math.nan)
    return SpeedMap(number, depth, tuple(speeds), tuple(growth), tuple(chip), study_file, result.summary_file,
                    time.perf_counter() - t0)


def merged(a: SpeedMap, b: SpeedMap) -> SpeedMap:
    """Both maps' speeds in one, sorted (a speed in both: ``b``'s)."""
    table = {**dict(zip(a.speeds, zip(a.growth, a.chip))), **dict(zip(b.speeds, zip(b.growth, b.chip)))}
    speeds = sorted(table)
    return SpeedMap(a.tool, a.depth, tuple(speeds), tuple(table[s][0] for s in speeds),
                    tuple(table[s][1] for s in speeds), b.study, b.summary, a.wall_time + b.wall_time)


def least_chatter(speed_map: SpeedMap) -> float:
    """The speed whose dynamic chip is smallest (when no speed is stable)."""
    chip = np.nan_to_num(np.asarray(speed_map.chip, dtype=float), nan=np.inf)
    return float(speed_map.speeds[int(np.argmin(chip))])


def pocket_speed(speed_map: SpeedMap, programmed: float) -> float | None:
    """The stable speed closest to ``programmed`` inside a pocket (its grid neighbours stable), else the closest
    stable one, None when no speed is stable."""
    stable = speed_map.stable
    speeds = np.asarray(speed_map.speeds)
    order = np.argsort(np.abs(speeds - programmed), kind="stable")
    inside = [i for i in order if stable[i] and all(stable[j] for j in (i - 1, i + 1) if 0 <= j < len(stable))]
    anywhere = [i for i in order if stable[i]]
    pick = inside or anywhere
    return float(speeds[pick[0]]) if pick else None
