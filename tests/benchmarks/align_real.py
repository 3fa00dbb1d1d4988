"""The real alignment case: the interpolator's run of the program reconstructed from UMich run 01
(scenarios/umich_motion.toml) against the recorded actual positions of that run.

    .venv/bin/python tests/benchmarks/align_real.py [--fmu-dir build/fmus]

Reports the residual path error |p_recorded(t) - p_simulated(map(t))| per method (median, p95, RMS,
max, mm), before alignment (identity time map) and after, and the wall time of each alignment.
"""
from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from milling_twin.orchestrator.align import align, path_residual
from milling_twin.orchestrator.align.trajectory import Trajectory
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.results import load_results
from milling_twin.orchestrator.scenario import load_scenario

REPO = Path(__file__).resolve().parents[2]
COLUMNS = ["interp.x", "interp.y", "interp.z"]


def describe(label: str, distance: np.ndarray, seconds: float | None = None) -> str:
    mm = distance * 1e3
    timing = f", {seconds:.2f} s" if seconds is not None else ""
    return (f"{label:>24}: median {np.median(mm):7.3f}  p95 {np.percentile(mm, 95):7.3f}  "
            f"RMS {np.sqrt(np.mean(mm ** 2)):7.3f}  max {np.max(mm):7.3f} mm{timing}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--fmu-dir", type=Path, default=REPO / "build" / "fmus")
    args = parser.parse_args()
    scenario = load_scenario(REPO / "scenarios" / "umich_motion.toml", args.fmu_dir)
    with tempfile.TemporaryDirectory() as out:
        results = load_results(run(scenario, out, progress=False).run_dir)
    recorded = Trajectory.from_recorded(scenario.recorded, ("x_actual", "y_actual", "z_actual"))
    simulated = Trajectory.from_results(results, COLUMNS, name="interpolator")
    sim_at_same_time = simulated.at(np.clip(recorded.time, simulated.time[0], simulated.time[-1]))
    print(f"UMich run 01: {len(recorded.time)} recorded samples (10 Hz), {len(simulated.time)} simulated rows")
    print(describe("identity (no alignment)", np.linalg.norm(recorded.position - sim_at_same_time, axis=1)))
    for method in ("multiscale", "dtw", "patent"):
        start = time.perf_counter()
        time_map = align(recorded, simulated, method)
        seconds = time.perf_counter() - start
        residual = path_residual(time_map, recorded, simulated)
        print(describe(method, residual.distance[np.isfinite(residual.distance)], seconds))


if __name__ == "__main__":
    main()
