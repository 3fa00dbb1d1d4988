"""Per-step cost of the orchestrator on the power scenario (Python and fast path), against a bare fmpy loop in the same run.

    .venv/bin/python tests/benchmarks/power_steps.py [--repeat 3]

The baseline steps the same two FMUs the same number of times with the same step sizes in a
hand-written fmpy loop (FMU3Slave: set inputs, doStep, get outputs; constant inputs, nothing
recorded), i.e. the least a Python master on fmpy can do. The ratio orchestrator / baseline is
what the orchestrator's scenario handling, recorded-input interpolation and result writing cost;
the machines are shared and noisy, so compare ratios, not absolute times. Best of --repeat runs.
"""
from __future__ import annotations

import argparse
import shutil
import tempfile
import time
from pathlib import Path

from fmpy import extract, read_model_description
from fmpy.fmi3 import FMU3Slave

from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.scenario import load_scenario

REPO = Path(__file__).resolve().parents[2]


def bare_fmpy_loop(fmu_dir: Path, stop_time: float) -> tuple[float, int]:
    """Wall time and doStep count of SpindlePower at 1 ms and MrrEstimator at 10 ms, fed by hand."""
    slaves = {}
    for name, h in (("MrrEstimator", 0.01), ("SpindlePower", 0.001)):
        path = fmu_dir / f"{name}.fmu"
        md = read_model_description(path)
        folder = extract(path)
        slave = FMU3Slave(guid=md.guid, unzipDirectory=folder, modelIdentifier=md.coSimulation.modelIdentifier,
                          instanceName=name)
        slave.instantiate()
        slave.enterInitializationMode(startTime=0.0)
        slave.exitInitializationMode()
        vrs = {v.name: v.valueReference for v in md.modelVariables}
        slaves[name] = (slave, folder, h, vrs)
    mrr, _, _, mrr_vr = slaves["MrrEstimator"]
    power, _, _, power_vr = slaves["SpindlePower"]
    feed_vrs, mrr_out = [mrr_vr["feed_velocity_x"], mrr_vr["feed_velocity_y"]], [mrr_vr["mrr"]]
    power_in = [power_vr["spindle_speed"], power_vr["mrr"]]
    power_out = [power_vr["P_total"], power_vr["P_spindle"], power_vr["P_cutting"]]
    ticks = round(stop_time / 0.001)
    steps = 0
    start = time.perf_counter()
    value = [0.0]
    for k in range(ticks):
        t = k * 0.001
        if k % 10 == 0:
            mrr.setFloat64(feed_vrs, [0.01, 0.002])
            mrr.doStep(t, 0.01)
            value = mrr.getFloat64(mrr_out)
            steps += 1
        power.setFloat64(power_in, [335.0, value[0]])
        power.doStep(t, 0.001)
        power.getFloat64(power_out)
        steps += 1
    elapsed = time.perf_counter() - start
    for slave, folder, _, _ in slaves.values():
        slave.terminate()
        slave.freeInstance()
        shutil.rmtree(folder, ignore_errors=True)
    return elapsed, steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--fmu-dir", type=Path, default=REPO / "build" / "fmus")
    args = parser.parse_args()
    scenario = load_scenario(REPO / "scenarios" / "umich_power.toml", args.fmu_dir)
    best_run, best_loop, best_base, best_fast = float("inf"), float("inf"), float("inf"), float("inf")
    with tempfile.TemporaryDirectory() as out:
        for _ in range(args.repeat):
            result = run(scenario, out, progress=False, stepping="python")
            best_run = min(best_run, result.wall_time)
            best_loop = min(best_loop, result.loop_wall_time)
            fast = run(scenario, out, progress=False, stepping="fast")
            best_fast = min(best_fast, fast.wall_time)
            base_time, base_steps = bare_fmpy_loop(args.fmu_dir, result.end_time)
            best_base = min(best_base, base_time)
    print(f"umich_power: {result.steps} base steps (1 ms), {result.fmu_steps} doStep calls, "
          f"{result.end_time:g} s simulated")
    print(f"orchestrator stepping loop: {best_loop:.3f} s = {result.steps / best_loop:,.0f} steps/s "
          f"({best_loop / result.fmu_steps * 1e6:.2f} us per doStep)")
    print(f"orchestrator end to end   : {best_run:.3f} s (setup, stepping, results, run.json)")
    print(f"bare fmpy loop (baseline) : {best_base:.3f} s = {result.steps / best_base:,.0f} steps/s "
          f"for {base_steps} doStep calls")
    print(f"ratio orchestrator loop / bare fmpy loop: {best_loop / best_base:.2f}; "
          f"real-time factor {result.end_time / best_run:.0f}x")
    print(f"orchestrator fast path, end to end: {best_fast:.3f} s = {result.steps / best_fast:,.0f} steps/s; "
          f"{best_base / best_fast:.0f}x faster than the bare fmpy loop, real-time factor "
          f"{result.end_time / best_fast:.0f}x")


if __name__ == "__main__":
    main()
