"""The whole-part scenarios: the engagement-driven variable step against the all-fine-step run, speed, volumes.

    .venv/bin/python tests/benchmarks/whole_part.py [--fmu-dir build/fmus] [--out runs/benchmarks/whole_part]
        [--parts scenarios/al_bracket.toml scenarios/umich_part.toml scenarios/al_plate.toml] [--repeat 3]
        [--generated SEED ...]   # and parts of random programs (generated_parts.py)

Per part, in one process and one after the other (ratios of runs made minutes apart on the same machine):

- the part as written (force and vibration at 10 us in and near material, one 1 ms step in air: ``[stepping]``)
  and the same scenario without ``[stepping]`` (force and vibration at 10 us throughout: the all-fine run), both
  on the fast path, ``--repeat`` times each, alternating; the fastest stepping loop of each and their ratio; the
  real-time factor of the variable run (simulated machining time / wall time of the loop, and / wall time of the
  whole command: set-up, loop, writing, comparisons and the process report);
- in material (rows with ``workpiece.axial_depth`` > 0 in the all-fine run): the RMS difference of Fx, Fy, torque
  and the tip deflection x and y between the two runs, relative to the all-fine run's RMS of each, over the rows
  of the stretches in material that hold no chattering block (the all-fine run's process report) and over all
  in-cut rows. A chattering cut is unstable: rounding differences (those of a 1 ms step against a hundred 10 us
  ones of the same exact discretization) grow in it as the chatter does, so its time series part; there, per
  chattering block, the runs' chatter flags and the relative differences of the block's mean and maximum force
  and maximum deflection; and, as the yardstick, the same figures of the all-fine run against itself with the
  tool's first x stiffness changed by 1e-13 of it (run only for a part with chattering blocks);
- the machining time (the last row at which the Interpolator's position changes) of both, the removed volume
  (the Workpiece's ``removed_volume`` at the end) of both, and against stock - final Z-map volume;
- per straight cut at constant depth, the volume removed over its steady part against width x length x depth
  (the process report's ``volume_ratio``): count, mean, min, max.

Printed as a table; every figure in ``OUT/whole_part.json``. A part whose run fails (an FMU error: chatter grown out
of the force model's input range, say) is reported with its message, and the others are measured.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

import milling_twin
from generated_parts import write_generated_part
from milling_twin.api import default_fmu_dir
from milling_twin.orchestrator.part.model import FORCE, INTERPOLATOR, VIBRATION, WORKPIECE
from milling_twin.orchestrator.scenario import Scenario

REPO = Path(__file__).resolve().parents[2]
PARTS = (REPO / "scenarios" / "al_bracket.toml", REPO / "scenarios" / "umich_part.toml",
         REPO / "scenarios" / "al_plate.toml")
COMPARED = (f"{FORCE}.Fx", f"{FORCE}.Fy", f"{FORCE}.torque", f"{VIBRATION}.tip_displacement_x",
            f"{VIBRATION}.tip_displacement_y")


def machining_time(frame: pd.DataFrame) -> float:
    """The last output time at which the tool's position changed."""
    xyz = frame[[f"{INTERPOLATOR}.x", f"{INTERPOLATOR}.y", f"{INTERPOLATOR}.z"]].to_numpy()
    moving = np.flatnonzero(np.any(np.diff(xyz, axis=0) != 0.0, axis=1))
    return float(frame["time"].to_numpy()[moving[-1] + 1]) if moving.size else 0.0


def measure(path: Path, fmu_dir: Path, out: Path, repeat: int) -> dict:
    scenario = milling_twin.load_scenario(path, fmu_dir)
    cases = (("variable", scenario),
             ("all_fine", dataclasses.replace(scenario, stepping=None, name=f"{scenario.name}_all_fine")))
    runs: dict[str, tuple] = {}
    loops: dict[str, list[float]] = {label: [] for label, _ in cases}
    walls: dict[str, list[float]] = {label: [] for label, _ in cases}
    for _ in range(repeat):  # alternating, so that a change of the machine's load hits both alike
        for label, case in cases:
            start = time.perf_counter()
            res = milling_twin.simulate(case, out=out, stepping="fast")
            walls[label].append(time.perf_counter() - start)
            loops[label].append(res.run.loop_wall_time)
            runs[label] = res
    var, fine = runs["variable"], runs["all_fine"]
    var_wall, fine_wall = min(walls["variable"]), min(walls["all_fine"])
    var_loop, fine_loop = min(loops["variable"]), min(loops["all_fine"])
    a, b = var.frame, fine.frame
    assert np.array_equal(a["time"].to_numpy(), b["time"].to_numpy())
    cut = b[f"{WORKPIECE}.axial_depth"].to_numpy() > 0.0
    fine_blocks = _blocks(fine.run.run_dir)
    agreement = _agreement(var, fine, fine_blocks)
    t_var, t_fine = machining_time(a), machining_time(b)
    v_var = float(a[f"{WORKPIECE}.removed_volume"].iloc[-1])
    v_fine = float(b[f"{WORKPIECE}.removed_volume"].iloc[-1])
    process = var.process_report
    ratios = _volume_ratios(var.run.run_dir)
    return {
        "part": path.name if path.name != "part.toml" else path.parent.name,
        "simulated_time": var.run.end_time, "rows": var.run.rows,
        "fine_intervals": var.run.fine_intervals, "coarse_intervals": var.run.coarse_intervals,
        "in_material_fraction": float(np.mean(cut)),
        "repeat": repeat, "loop_wall_times": loops, "command_wall_times": walls,
        "loop_wall_time": {"variable": var_loop, "all_fine": fine_loop},
        "command_wall_time": {"variable": var_wall, "all_fine": fine_wall},
        "fmu_steps": {"variable": var.run.fmu_steps, "all_fine": fine.run.fmu_steps},
        "speedup_loop": fine_loop / var_loop,
        "speedup_command": fine_wall / var_wall,
        "real_time_factor_loop": t_var / var_loop,
        "real_time_factor_command": t_var / var_wall,
        **agreement,
        "perturbed_all_fine": _perturbed(fine, fine_blocks, cases[1][1], out)
        if agreement["chattering_blocks"]["count"] else None,
        "machining_time": {"variable": t_var, "all_fine": t_fine},
        "removed_volume": {"variable": v_var, "all_fine": v_fine,
                           "relative_difference": abs(v_var - v_fine) / v_fine if v_fine else 0.0,
                           "stock_minus_zmap": process.removed_volume_zmap if process else None},
        "volume_ratio_straight_cuts": {"count": int(ratios.size),
                                       "mean": float(np.mean(ratios)) if ratios.size else None,
                                       "min": float(np.min(ratios)) if ratios.size else None,
                                       "max": float(np.max(ratios)) if ratios.size else None},
        "process_report": str(process.html) if process else None,
    }


PERTURBATION = 1e-13  # relative, of the all-fine run's stiffness_x1: the yardstick of rounding in chatter


def _agreement(run: Any, reference: Any, reference_blocks: pd.DataFrame) -> dict:
    """``run`` against ``reference`` (two results of the same part): the RMS differences over the in-cut
    stretches holding no chattering block of the reference and over every in-cut row, the share of rows in those
    stretches, and the chattering blocks' agreement."""
    a, b = run.frame, reference.frame
    cut = b[f"{WORKPIECE}.axial_depth"].to_numpy() > 0.0
    chattering = reference_blocks.loc[reference_blocks["chatter"].astype(bool), "line"].to_numpy() \
        if "chatter" in reference_blocks else np.zeros(0)
    stable_cut = _stable_rows(cut, np.isin(b[f"{INTERPOLATOR}.line_number"].to_numpy(), chattering))
    return {"rms_difference_in_material": _rms_differences(a, b, stable_cut),
            "in_material_stable_fraction": float(np.mean(stable_cut)),
            "rms_difference_in_material_all": _rms_differences(a, b, cut),
            "chattering_blocks": _chatter_agreement(_blocks(run.run.run_dir), reference_blocks)}


def _perturbed(fine: Any, fine_blocks: pd.DataFrame, scenario: Scenario, out: Path) -> dict:
    """The all-fine run ``fine`` of ``scenario`` against itself with stiffness_x1 of the vibration times
    1 + PERTURBATION (:func:`_agreement`)."""
    def changed(inst: Any) -> Any:
        if inst.name != VIBRATION:
            return inst
        return dataclasses.replace(inst, parameters={**inst.parameters, "stiffness_x1": inst.parameters[
            "stiffness_x1"] * (1.0 + PERTURBATION)})

    case = dataclasses.replace(scenario, name=f"{scenario.name}_perturbed",
                               instances=tuple(changed(inst) for inst in scenario.instances))
    res = milling_twin.simulate(case, out=out, stepping="fast")
    return {"relative_change": PERTURBATION, **_agreement(res, fine, fine_blocks)}


def _blocks(run_dir: Path) -> pd.DataFrame:
    """The process report's block table of a run (empty without one)."""
    path = run_dir / "blocks.parquet"
    return pd.read_parquet(path) if path.is_file() else pd.DataFrame()


def _volume_ratios(run_dir: Path) -> np.ndarray:
    """The process report's removed / analytic volume of the straight cuts at constant depth."""
    blocks = _blocks(run_dir)
    return blocks["volume_ratio"].dropna().to_numpy() if "volume_ratio" in blocks else np.zeros(0)


def _stable_rows(cut: np.ndarray, chattering: np.ndarray) -> np.ndarray:
    """The in-cut rows of the stretches in material (runs of consecutive ``cut`` rows) that hold no row of a
    chattering block: the chatter of a slot goes on into the retract that leaves it."""
    starts = np.flatnonzero(cut & ~np.concatenate(([False], cut[:-1])))
    stretch = np.cumsum(np.isin(np.arange(cut.size), starts)) * cut  # 1, 2, ... per stretch, 0 in air
    bad = np.unique(stretch[cut & chattering])
    return cut & ~np.isin(stretch, bad)


def _rms_differences(a: pd.DataFrame, b: pd.DataFrame, rows: np.ndarray) -> dict[str, float | None]:
    """RMS of a - b over ``rows`` relative to b's RMS there, per compared column (None without rows)."""
    out: dict[str, float | None] = {}
    for column in COMPARED:
        x, y = a[column].to_numpy()[rows], b[column].to_numpy()[rows]
        rms = float(np.sqrt(np.mean(y ** 2))) if y.size else 0.0
        out[column] = float(np.sqrt(np.mean((x - y) ** 2))) / rms if rms > 0 else (0.0 if y.size else None)
    return out


BLOCK_FIGURES = ("force_mean", "force_max", "deflection_max")  # N, N, m (blocks.parquet: SI)


def _chatter_agreement(var_blocks: pd.DataFrame, fine_blocks: pd.DataFrame) -> dict:
    """The blocks that chatter in the all-fine run: how many, in how many the variable run flags chatter too, and
    the largest relative difference of each of BLOCK_FIGURES between the runs over them."""
    if "chatter" not in fine_blocks or len(var_blocks) != len(fine_blocks):
        return {"count": 0}
    flagged = fine_blocks["chatter"].astype(bool).to_numpy()
    out: dict = {"count": int(flagged.sum()), "lines": fine_blocks["line"].to_numpy()[flagged].tolist(),
                 "flagged_in_both": int((flagged & var_blocks["chatter"].astype(bool).to_numpy()).sum())}
    for column in BLOCK_FIGURES:
        x, y = var_blocks[column].to_numpy()[flagged], fine_blocks[column].to_numpy()[flagged]
        out[column] = float(np.max(np.abs(x - y) / np.abs(y))) if flagged.any() else None
    return out


def _measured_or_failed(path: Path, fmu_dir: Path, out: Path, repeat: int) -> dict:
    """:func:`measure`, or the part's failure (a run that ends in an FMU error, say) so that the others are measured
    too: a benchmark over many random programs reports each one."""
    try:
        return measure(path, fmu_dir, out, repeat)
    except Exception as exc:  # noqa: BLE001 - recorded in the table and the JSON, the next part runs
        name = path.name if path.name != "part.toml" else path.parent.name
        return {"part": name, "failed": f"{type(exc).__name__}: {exc}"}


def _percent(value: float | None) -> str:
    return "n/a" if value is None else f"{100 * value:.3g} %"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fmu-dir", type=Path, default=default_fmu_dir())
    parser.add_argument("--out", type=Path, default=Path("runs/benchmarks/whole_part"))
    parser.add_argument("--parts", type=Path, nargs="*", default=list(PARTS), help="none: the generated ones only")
    parser.add_argument("--repeat", type=int, default=3, help="runs of each, alternating; the fastest counts")
    parser.add_argument("--generated", type=int, nargs="*", default=[], metavar="SEED",
                        help="also parts of random programs with these seeds (tests/benchmarks/generated_parts.py)")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    parts = list(args.parts) + [write_generated_part(args.out / "programs", seed) for seed in args.generated]
    results = [_measured_or_failed(path, args.fmu_dir, args.out, args.repeat) for path in parts]
    for r in results:
        if "failed" in r:
            print(f"{r['part']}: FAILED: {r['failed']}")
            continue
        d = r["rms_difference_in_material"]
        print(f"{r['part']}: {r['simulated_time']:.1f} s simulated, in material {100 * r['in_material_fraction']:.1f} %"
              f" of the rows, {r['fine_intervals']} of {r['fine_intervals'] + r['coarse_intervals']} intervals fine")
        print(f"  loop wall time: variable {r['loop_wall_time']['variable']:.2f} s, all-fine "
              f"{r['loop_wall_time']['all_fine']:.2f} s: {r['speedup_loop']:.2f}x; whole command "
              f"{r['command_wall_time']['variable']:.2f} s vs {r['command_wall_time']['all_fine']:.2f} s: "
              f"{r['speedup_command']:.2f}x; doSteps {r['fmu_steps']['variable']} vs {r['fmu_steps']['all_fine']}")
        print(f"  real-time factor (variable): {r['real_time_factor_loop']:.2f} (loop), "
              f"{r['real_time_factor_command']:.2f} (whole command)")
        print(f"  RMS difference in material / RMS, stretches in material without chatter "
              f"({100 * r['in_material_stable_fraction']:.1f} % of the rows): " + ", ".join(f"{k} {_percent(v)}" for k, v in d.items()))
        c = r["chattering_blocks"]
        if c["count"]:
            print(f"  chattering blocks (lines {', '.join(map(str, c['lines']))}): flagged in both runs "
                  f"{c['flagged_in_both']} of {c['count']}; largest relative difference "
                  + ", ".join(f"{k} {100 * c[k]:.3g} %" for k in BLOCK_FIGURES)
                  + "; RMS difference of all in-cut rows / RMS: "
                  + ", ".join(f"{k} {_percent(v)}" for k, v in r["rms_difference_in_material_all"].items()))
            p = r["perturbed_all_fine"]
            pc = p["chattering_blocks"]
            print(f"  yardstick, the all-fine run against itself with stiffness_x1 x (1 + {p['relative_change']:g}): "
                  f"chatter flagged in both {pc['flagged_in_both']} of {pc['count']}; largest relative difference "
                  + ", ".join(f"{k} {100 * pc[k]:.3g} %" for k in BLOCK_FIGURES)
                  + "; RMS difference of all in-cut rows / RMS: "
                  + ", ".join(f"{k} {_percent(v)}" for k, v in p["rms_difference_in_material_all"].items())
                  + "; without chatter: "
                  + ", ".join(f"{k} {_percent(v)}" for k, v in p["rms_difference_in_material"].items()))
        m, v = r["machining_time"], r["removed_volume"]
        zmap = v["stock_minus_zmap"]
        print(f"  machining time {m['variable']:.4f} s vs {m['all_fine']:.4f} s; removed volume "
              f"{v['variable'] * 1e6:.6f} vs {v['all_fine'] * 1e6:.6f} cm3 (relative difference "
              f"{v['relative_difference']:.2e}); stock - final Z-map "
              + (f"{zmap * 1e6:.6f} cm3" if zmap is not None else "n/a"))
        q = r["volume_ratio_straight_cuts"]
        if q["count"]:
            print(f"  straight cuts at constant depth: {q['count']} blocks, removed / analytic volume mean "
                  f"{q['mean']:.4f} (min {q['min']:.4f}, max {q['max']:.4f})")
    path = args.out / "whole_part.json"
    path.write_text(json.dumps(results, indent=2))
    print(f"figures: {path}")


if __name__ == "__main__":
    main()
