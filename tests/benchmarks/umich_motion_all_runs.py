"""All twelve UMich recordings through reconstruct -> Interpolator -> alignment, one consistent segment at a time.

    .venv/bin/python tests/benchmarks/umich_motion_all_runs.py [--data ../shared/data/umich_cnc] [--fmu-dir build/fmus]

(--data default: $MILLING_TWIN_UMICH_DATA, else ../shared/data/umich_cnc relative to the repository.) Per run:
the recording is cut into consistent segments (recording_checks, policy segment) and one program is rebuilt per
segment (orchestrator/gcode/reconstruct.py); each program runs on the Interpolator FMU through the orchestrator
(a scenario per segment with reconstruct.INTERPOLATOR_PARAMETERS and the segment's first position, 5 ms steps);
the simulated duration is the first output time with interp.finished. Each segment's recorded actual positions
are aligned with its run (orchestrator/align/segments.py: multiscale, the program's start offset and the segment
fit, with the recorded axis velocities and the storage steps of 3 significant digits). Printed per run: rows,
segments with a program (of which standing: no motion) / without (a single row), programs the Interpolator
refused, duration ratio simulated/recorded over the programs with motion (total and worst segment), the share of
cutting samples ('Layer' rows with the spindle running) whose residual after alignment is within
1.5 storage steps on every axis (3 significant digits: 1 mm in X, 0.1 mm in Y and Z; samples of segments
without a program or without a map count as misses), the median segment confidence and the segments below
DEFAULT_MIN_CONFIDENCE.
"""
from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from milling_twin.api import simulate
from milling_twin.orchestrator.align.segments import DEFAULT_MIN_CONFIDENCE, align_segments
from milling_twin.orchestrator.align.trajectory import Trajectory
from milling_twin.orchestrator.gcode import reconstruct as rc
from milling_twin.orchestrator.recording_checks import quantum_of_significant_digits
from milling_twin.orchestrator.scenario import ScenarioError
from milling_twin.orchestrator.master import SimulationError

REPO = Path(__file__).resolve().parents[2]
STEP = 0.005  # s, the Interpolator's communication step and output interval here
TOLERANCE_STEPS = 1.5


def segment_scenario(folder: Path, segment: rc.SegmentProgram) -> Path:
    """A scenario running the segment's program from its first position."""
    program = folder / f"{segment.name}.nc"
    program.write_text(segment.recon.program())
    parameters = {**rc.INTERPOLATOR_PARAMETERS,
                  **{f"start_{a}": float(rc._mm(c)) * 1e-3 for a, c in zip("xyz", segment.recon.start)}}
    lines = ["[scenario]", f'name = "{segment.name}"', f"stop_time = {segment.simulated_time + 0.5:.3f}",
             f"output_interval = {STEP}", "[fmus.interp]", 'fmu = "Interpolator"', f"step_size = {STEP}",
             "[fmus.interp.parameters]", f'program = {{ path = "{program.name}" }}',
             *(f"{k} = {float(v)!r}" for k, v in parameters.items()),
             "[fmus.interp.inputs]", "feed_override = 1.0", "[outputs]",
             'record = ["interp.x", "interp.y", "interp.z", "interp.finished"]']
    path = folder / f"{segment.name}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


def run_one(csv: Path, fmu_dir: Path) -> dict[str, object]:
    data = pd.read_csv(csv)
    segmented = rc.reconstruct_segments(csv)
    actual = data[[f"{a}1_ActualPosition" for a in "XYZ"]].to_numpy(dtype=float) * 1e-3
    velocity = data[[f"{a}1_ActualVelocity" for a in "XYZ"]].to_numpy(dtype=float) * 1e-3
    time_s = np.arange(len(data)) * rc.SAMPLE_PERIOD
    recorded = Trajectory(time_s, actual, csv.name)
    refused, ratios, sims, rec_times = 0, [], {}, []
    with tempfile.TemporaryDirectory() as tmp:
        for s in segmented.programs:
            try:
                frame = simulate(segment_scenario(Path(tmp), s), fmu_dir=fmu_dir).frame
            except (ScenarioError, SimulationError):
                refused += 1
                continue
            done = frame["time"][frame["interp.finished"] > 0.5]
            duration = float(done.iloc[0]) if len(done) else float(frame["time"].iloc[-1])
            if not s.standing:
                ratios.append(duration / s.recorded_time)
                rec_times.append((s.recorded_time, duration))
            sims[s.index] = Trajectory(frame["time"].to_numpy(), frame[["interp.x", "interp.y", "interp.z"]]
                                       .to_numpy(), f"{csv.name} {s.name}")
    t0 = time.perf_counter()
    pieces = [(s.index, s.start, s.stop, sims.get(s.index), s.motion_start) for s in segmented.segments]
    quantum = quantum_of_significant_digits(actual, rc.SIGNIFICANT_DIGITS)
    piecewise = align_segments(recorded, pieces, velocity=velocity, step=quantum)
    align_time = time.perf_counter() - t0
    within = np.zeros(len(data), dtype=bool)
    for seg in piecewise.segments:
        if seg.time_map is None:
            continue
        sim = sims[seg.index]
        mapped = seg.time_map.resample_simulated(sim.time, sim.position)
        residual = np.abs(actual[seg.start:seg.stop] - mapped)
        within[seg.start:seg.stop] = np.all(residual <= TOLERANCE_STEPS * quantum[seg.start:seg.stop] + 1e-12,
                                            axis=1)
    layer = data["Machining_Process"].astype(str).str.startswith("Layer").to_numpy()
    cutting = layer & (data["S1_ActualVelocity"].to_numpy(dtype=float) > rc.SPINDLE_ON)
    total_rec = sum(r for r, _ in rec_times)
    total_sim = sum(d for _, d in rec_times)
    confidences = [s.confidence for s in piecewise.segments if s.time_map is not None]
    worst = max(ratios, key=lambda r: abs(r - 1.0)) if ratios else float("nan")
    return {"run": csv.stem.split("_")[-1], "rows": len(data), "segments": len(segmented.segments),
            "used": len(segmented.programs), "standing": len(segmented.programs) - len(segmented.moving), "dropped": len(segmented.segments) - len(segmented.programs),
            "refused": refused, "total": total_sim / total_rec if total_rec else float("nan"), "worst": worst,
            "cutting": int(cutting.sum()), "layer": int(layer.sum()), "within": float(within[cutting].mean()) if cutting.any() else float("nan"),
            "confidence": float(np.median(confidences)) if confidences else 0.0,
            "below": len([s for s in piecewise.below(DEFAULT_MIN_CONFIDENCE) if s.index in sims]),
            "align_s": align_time}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    default = os.environ.get("MILLING_TWIN_UMICH_DATA", str(REPO.parent / "shared" / "data" / "umich_cnc"))
    parser.add_argument("--data", type=Path, default=Path(default))
    parser.add_argument("--fmu-dir", type=Path, default=Path(os.environ.get("MILLING_TWIN_FMU_DIR",
                                                                            REPO / "build" / "fmus")))
    parser.add_argument("--runs", type=int, nargs="*", default=list(range(1, 13)))
    args = parser.parse_args()
    print("| run | rows | segments with program (standing) / without | refused | duration sim/rec total | worst segment "
          "| cutting samples within 1.5 steps | median confidence | segments below "
          f"{DEFAULT_MIN_CONFIDENCE:g} |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    start = time.perf_counter()
    for run in args.runs:
        r = run_one(args.data / f"experiment_{run:02d}.csv", args.fmu_dir)
        print(f"| {r['run']} | {r['rows']} | {r['used']} ({r['standing']}) / {r['dropped']} | {r['refused']} | {r['total']:.4f} | "
              f"{r['worst']:.4f} | {100 * r['within']:.1f} % of {r['cutting']} | {r['confidence']:.2f} | "
              f"{r['below']} |", flush=True)
    print(f"({time.perf_counter() - start:.0f} s)")


if __name__ == "__main__":
    main()
