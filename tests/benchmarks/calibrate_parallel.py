"""Parallel calibration benchmark (orchestrator/calibrate/parallel.py): fits through the FMUs, serially and with
their simulations on N local dask worker processes, in the same run, alternating, best of ``--rounds``.

    .venv/bin/python tests/benchmarks/calibrate_parallel.py [--rounds 3] [--workers 2] [--fmu-dir build/fmus]

Cases (each fit from an empty evaluation cache; the cluster is started once, its start time printed apart):

* ``slot``: scenarios/calibration/slot_forces_synthetic.toml as committed (six CuttingForce coefficients,
  3 starts, 0.03 s of slot milling per simulation);
* ``umich_power (FD)``: scenarios/calibration/umich_power.toml with ``[solver].derivatives =
  "finite-differences"`` (five SpindlePower parameters, 4 starts, the 105 s UMich run per simulation);
* ``closed loop 1 s``: the force/vibration loop of scenarios/chatter.toml cut for 1 s (CuttingForce and
  ToolVibration at 10 us, the displacement fed back with a delay), force.Ktc and vibration.stiffness_x1 fitted
  from the force and the tip displacement the FMUs give with known values, 3 starts.

Printed per case: simulations per fit, their mean time in the serial fit, the fit's wall time serial and
parallel (best of the rounds) and their ratio, and whether every number of the fits is the same (estimates,
each start's objective and iterations, covariance, simulation count).
"""
from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: the generated cases (tests/cases)

from cases.calibration_recovery import RecoveryStudy  # noqa: E402
from cases.calibration_synthetic import edited, load_scenario_without_data  # noqa: E402
from milling_twin.orchestrator.calibrate import load_spec  # noqa: E402
from milling_twin.orchestrator.calibrate.fit import FitOutcome, fit  # noqa: E402
from milling_twin.orchestrator.calibrate.pairing import LEARNING, Pairs  # noqa: E402
from milling_twin.orchestrator.calibrate.scenario_fit import Prepared, pairs_for, prepare  # noqa: E402
from milling_twin.orchestrator.study.executor import open_executor  # noqa: E402

REPO = Path(__file__).resolve().parents[2]
CALIBRATION = REPO / "scenarios" / "calibration"


@dataclass
class Case:
    name: str
    prepared: Prepared
    learning: Pairs
    recorded: np.ndarray


def slot_case(fmu_dir: Path, tmp: Path) -> Case:
    spec = load_spec(CALIBRATION / "slot_forces_synthetic.toml")
    spec = replace(spec, parameter_set=tmp / "slot.params.toml")
    prepared = prepare(spec, fmu_dir, tmp / "slot")
    learning = pairs_for(prepared)[0].select(LEARNING)
    return Case("slot (6 parameters, 3 starts)", prepared, learning, learning.recorded)


def umich_case(fmu_dir: Path, tmp: Path) -> Case:
    spec = load_spec(CALIBRATION / "umich_power.toml")
    spec = replace(spec, parameter_set=tmp / "umich.params.toml", calibrated_scenario=None,
                   solver=replace(spec.solver, derivatives="finite-differences"))
    prepared = prepare(spec, fmu_dir, tmp / "umich")
    learning = pairs_for(prepared)[0].select(LEARNING)
    return Case("umich_power FD (5 parameters, 4 starts)", prepared, learning, learning.recorded)


def loop_case(fmu_dir: Path, tmp: Path) -> Case:
    folder = tmp / "loop"
    folder.mkdir(parents=True)
    text = edited((REPO / "scenarios" / "chatter.toml").read_text(), ("stop_time = 0.2", "stop_time = 1.0"),
                  ("output_interval = 1e-5 ", "output_interval = 1e-4 "))
    text += ('\n[recorded]\nfile = "loop.csv"\ntime_column = "time"\n[recorded.channels]\n'
             'fx = { column = "fx", unit = "N" }\ndx = { column = "dx", unit = "m" }\n')
    (folder / "loop.toml").write_text(text)
    load_scenario_without_data(folder / "loop.toml", fmu_dir, folder)
    (folder / "spec.toml").write_text(
        '[calibration]\nname = "loop"\nscenario = "loop.toml"\nparameter_set = "loop.params.toml"\n'
        '[parameters."force.Ktc"]\nmin = 100.0\nmax = 3000.0\nunit = "N/mm2"\nstart_range = [600.0, 1200.0]\n'
        '[parameters."vibration.stiffness_x1"]\nmin = 1e5\nmax = 1e8\nstart_range = [5e5, 2e6]\n'
        '[[outputs]]\nsimulated = "force.Fx"\nrecorded = "fx"\n'
        '[[outputs]]\nsimulated = "vibration.tip_displacement_x"\nrecorded = "dx"\n'
        '[segments]\nlearning = [[0.0, 1.0]]\n[solver]\nstarts = 3\n')
    study = RecoveryStudy(load_spec(folder / "spec.toml"), fmu_dir, folder / "out",
                          {"force.Ktc": 900e6, "vibration.stiffness_x1": 1.0e6})
    return Case("closed loop 1 s (2 parameters, 3 starts)", study.prepared, study.learning, study.learning.recorded)


def run_fit(case: Case, executor, workers: int = 0) -> tuple[FitOutcome, int, float, float]:
    """The case's fit, serial (no executor) or with its simulations on ``executor``'s ``workers`` local workers
    (as ``calibrate --workers`` runs it)."""
    spec = case.prepared.spec
    model = case.prepared.residual_model(case.learning)
    t0 = time.perf_counter()
    outcome = fit(model, case.recorded, weights=[o.weight for o in case.prepared.outputs],
                  sigma=[None] * len(case.prepared.outputs), solver=replace(spec.solver, workers=workers),
                  statistics=spec.statistics, executor=executor)
    fmu = model.keep_alive.fmu
    return outcome, fmu.simulations, fmu.simulation_time, time.perf_counter() - t0


def same(a: tuple, b: tuple) -> bool:
    (fa, na, _, _), (fb, nb, _, _) = a, b
    return (na == nb and np.array_equal(fa.theta, fb.theta)
            and [(s.objective, s.iterations, s.status) for s in fa.starts]
            == [(s.objective, s.iterations, s.status) for s in fb.starts]
            and np.array_equal(fa.statistics.covariance, fb.statistics.covariance, equal_nan=True))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--fmu-dir", type=Path,
                        default=Path(os.environ.get("MILLING_TWIN_FMU_DIR", REPO / "build" / "fmus")))
    args = parser.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        cases = [make(args.fmu_dir, Path(tmp)) for make in (slot_case, umich_case, loop_case)]
        t0 = time.perf_counter()
        with open_executor(args.workers) as executor:
            print(f"cluster of {args.workers} local worker processes started in {time.perf_counter() - t0:.2f} s")
            run_fit(cases[0], executor, args.workers)  # the workers import the package and unpack the FMUs once
            print(f"| case | simulations per fit | mean simulation [s] | serial [s] | {args.workers} workers [s] "
                  "| ratio | same numbers |")
            print("|---|---:|---:|---:|---:|---:|---|")
            for case in cases:
                serial, parallel, identical = [], [], True
                reference = None
                for k in range(args.rounds):
                    for mode in (("serial", "parallel") if k % 2 == 0 else ("parallel", "serial")):
                        result = (run_fit(case, executor, args.workers) if mode == "parallel" else
                                  run_fit(case, None))
                        (serial if mode == "serial" else parallel).append(result)
                        reference = reference or result
                        identical = identical and same(reference, result)
                best_serial = min(r[3] for r in serial)
                best_parallel = min(r[3] for r in parallel)
                sims, sim_time = serial[0][1], serial[0][2]
                print(f"| {case.name} | {sims} | {sim_time / sims:.4f} | {best_serial:.2f} | {best_parallel:.2f} "
                      f"| {best_serial / best_parallel:.2f} | {'yes' if identical else 'NO'} |", flush=True)


if __name__ == "__main__":
    main()
