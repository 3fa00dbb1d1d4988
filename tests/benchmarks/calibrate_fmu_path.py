"""Calibration benchmark of the FMU finite-difference path (orchestrator/calibrate/fmu_outputs.py).

    .venv/bin/python tests/benchmarks/calibrate_fmu_path.py [--repeats 20] [--rounds 2] [--fmu-dir build/fmus]
        [--out runs/benchmarks/calibrate_fmu_path]

1. **Exact vs finite differences on a model both can do** (SpindlePower + MrrEstimator), in the same run,
   alternating, best of ``--rounds``:
   * ``umich_power``: the demo spec scenarios/calibration/umich_power.toml (4 starts, DTW alignment, the
     real recording) as it is, and with ``[solver].derivatives = "finite-differences"``; the parameter set
     goes to the output folder (the bundled one is not touched). Reported: the fit stage's wall time (all
     starts, the second stage and the statistics; the alignment-effect refit is timed apart), the
     simulations, and the estimates' differences relative to the value and to the standard error.
   * ``power (synthetic inputs)``: the synthetic power case with 5 W noise (seed 0), one start each.
2. **Jacobian accuracy**: the finite-difference Jacobian (forward and central) of the synthetic power case's
   outputs at the truth against the exact one (casadi on the models/ equations): per parameter, the largest
   difference relative to the column's largest entry.
3. **Synthetic recovery through the FMU path**: scenarios/calibration/slot_forces_synthetic.toml
   (CuttingForce coefficients; the data the FMU makes with SLOT_TRUTH plus 5 N noise per force, one seed per
   repeat), one start per repeat (the problem is linear in the coefficients), ``--repeats`` repeats, and the
   noise-free relative error.
"""
from __future__ import annotations

import sys
import argparse
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from calibrate_recovery import print_case, study_case
from milling_twin.orchestrator.calibrate import load_spec
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: the generated cases (tests/cases)

from cases.calibration_recovery import RecoveryStudy
from milling_twin.orchestrator.calibrate.scenario_fit import calibrate_scenario
from cases.calibration_synthetic import POWER_TRUTH, SLOT_TRUTH, write_power_case

REPO = Path(__file__).resolve().parents[2]
UMICH = REPO / "scenarios" / "calibration" / "umich_power.toml"
SLOT = REPO / "scenarios" / "calibration" / "slot_forces_synthetic.toml"
FIT_STAGE = "fit (build, starts, statistics)"


def compare(exact: np.ndarray, fd: np.ndarray, se: np.ndarray, names: list[str]) -> dict:
    with np.errstate(divide="ignore", invalid="ignore"):
        rel = np.abs(fd - exact) / np.maximum(np.abs(exact), 1e-300)
        per_se = np.where(np.isfinite(se) & (se > 0), np.abs(fd - exact) / se, np.nan)
    return {"parameters": names, "exact": exact.tolist(), "fd": fd.tolist(),
            "max_relative_difference": float(np.max(rel)), "relative_difference": rel.tolist(),
            "max_difference_per_se": float(np.nanmax(per_se)) if np.isfinite(per_se).any() else None}


def umich(fmu_dir: Path, out: Path, rounds: int) -> dict:
    spec = load_spec(UMICH)
    spec = replace(spec, parameter_set=out / "umich_power.params.toml", calibrated_scenario=None)
    specs = {"exact": spec, "fd": replace(spec, solver=replace(spec.solver, derivatives="finite-differences"))}
    times: dict[str, list[float]] = {"exact": [], "fd": []}
    results = {}
    for k in range(rounds):
        for key in (("exact", "fd") if k % 2 == 0 else ("fd", "exact")):
            result = calibrate_scenario(specs[key], fmu_dir, out / key)
            times[key].append(result.timings[FIT_STAGE])
            results[key] = result
    exact, fd = results["exact"].fit, results["fd"].fit
    se = np.array([p.standard_error for p in exact.statistics.parameters])
    doc = compare(exact.theta, fd.theta, se, [q.name for q in exact.parameters])
    ident = np.array([p.identifiable for p in exact.statistics.parameters])
    doc["identified"] = [q.name for q, i in zip(exact.parameters, ident) if i]
    doc["max_relative_difference_identified"] = float(np.max(np.abs(fd.theta - exact.theta)[ident]
                                                             / np.abs(exact.theta[ident]))) if ident.any() else None
    doc.update(exact_fit_stage_s=min(times["exact"]), fd_fit_stage_s=min(times["fd"]),
               ratio=min(times["fd"]) / min(times["exact"]), objective_exact=exact.best.objective,
               objective_fd=fd.best.objective, flags_exact=[list(p.flags) for p in exact.statistics.parameters],
               flags_fd=[list(p.flags) for p in fd.statistics.parameters],
               fd_notes=[n for n in results["fd"].notes if n.startswith("FMU evaluations")])
    return doc


def synthetic_power(fmu_dir: Path, tmp: Path, rounds: int) -> dict:
    spec = load_spec(write_power_case(tmp / "case"))
    spec = replace(spec, solver=replace(spec.solver, starts=1))
    studies = {"exact": RecoveryStudy(spec, fmu_dir, tmp / "exact", POWER_TRUTH),
               "fd": RecoveryStudy(replace(spec, solver=replace(spec.solver, derivatives="finite-differences")),
                                   fmu_dir, tmp / "fd", POWER_TRUTH)}
    times: dict[str, list[float]] = {"exact": [], "fd": []}
    runs = {}
    for k in range(rounds):
        for key in (("exact", "fd") if k % 2 == 0 else ("fd", "exact")):
            if key == "fd":  # a repeated fit from the same start would find every evaluation cached
                studies[key].model.keep_alive.fmu.clear_cache()
            runs[key] = studies[key].run([5.0], 0)
            times[key].append(runs[key].wall_time)
    exact, fd = runs["exact"].outcome, runs["fd"].outcome
    se = np.array([p.standard_error for p in exact.statistics.parameters])
    doc = compare(exact.theta, fd.theta, se, [q.name for q in exact.parameters])
    se_fd = np.array([p.standard_error for p in fd.statistics.parameters])
    doc.update(exact_fit_s=min(times["exact"]), fd_fit_s=min(times["fd"]), ratio=min(times["fd"]) / min(times["exact"]),
               max_se_relative_difference=float(np.max(np.abs(se_fd - se) / se)))
    return doc


def jacobian_accuracy(fmu_dir: Path, tmp: Path) -> dict:
    spec = load_spec(write_power_case(tmp / "case"))
    exact = RecoveryStudy(spec, fmu_dir, tmp / "exact", POWER_TRUTH)
    theta, n, k = exact.truth, exact.model.n_pairs, exact.model.n_outputs
    p = np.concatenate([np.zeros(n * k), np.ones(k)])  # residual = outputs
    reference = exact.model.residual_jacobian(theta, p)[1]
    doc = {"parameters": [q.name for q in exact.prepared.parameters]}
    for method in ("forward", "central"):
        fd_spec = replace(spec, solver=replace(spec.solver, derivatives="finite-differences", fd_method=method))
        jac = RecoveryStudy(fd_spec, fmu_dir, tmp / method, POWER_TRUTH).model.residual_jacobian(theta, p)[1]
        doc[method] = (np.max(np.abs(jac - reference), axis=0) / np.max(np.abs(reference), axis=0)).tolist()
    return doc


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeats", type=int, default=20)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--fmu-dir", type=Path, default=Path(os.environ.get("MILLING_TWIN_FMU_DIR", REPO / "build" / "fmus")))
    parser.add_argument("--out", type=Path, default=REPO / "runs" / "benchmarks" / "calibrate_fmu_path")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        power = synthetic_power(args.fmu_dir, tmp / "power", args.rounds)
        umich_doc = umich(args.fmu_dir, tmp / "umich", args.rounds)
        jacobian = jacobian_accuracy(args.fmu_dir, tmp / "jacobian")
        spec = load_spec(SLOT)
        spec = replace(spec, parameter_set=tmp / "slot.params.toml", solver=replace(spec.solver, starts=1))
        slot = study_case("CuttingForce coefficients through the FMU (slot_forces_synthetic)",
                          RecoveryStudy(spec, args.fmu_dir, tmp / "slot", SLOT_TRUTH), [5.0, 5.0, 5.0], args.repeats)
    for name, doc, key in (("synthetic power case", power, "fit_s"), ("umich_power", umich_doc, "fit_stage_s")):
        print(f"\n### exact vs finite differences: {name}")
        print(f"fit: exact {doc['exact_' + key]:.3f} s, FMU finite differences {doc['fd_' + key]:.3f} s, ratio "
              f"{doc['ratio']:.0f} (best of {args.rounds})")
        print(f"estimates: max relative difference {doc['max_relative_difference']:.2e}, max difference / standard error "
              f"{doc['max_difference_per_se']}")
        for n, a, b in zip(doc["parameters"], doc["exact"], doc["fd"]):
            print(f"  {n}: exact {a:.10g}, fd {b:.10g}")
        for extra in ("max_se_relative_difference", "identified", "max_relative_difference_identified", "objective_exact", "objective_fd", "fd_notes"):
            if extra in doc:
                print(f"  {extra}: {doc[extra]}")
    print("\n### finite-difference Jacobian vs exact (synthetic power case at the truth; max error / column max)")
    for method in ("forward", "central"):
        print(f"{method}: " + ", ".join(f"{n} {e:.2e}" for n, e in zip(jacobian["parameters"], jacobian[method])))
    print_case(slot)
    doc = {"synthetic_power": power, "umich_power": umich_doc, "jacobian": jacobian, "slot_recovery": slot}
    (args.out / "calibrate_fmu_path.json").write_text(json.dumps(doc, indent=2, default=str))
    print(f"written: {args.out / 'calibrate_fmu_path.json'}")


if __name__ == "__main__":
    t0 = time.perf_counter()
    main()
    print(f"benchmark wall time {time.perf_counter() - t0:.0f} s")
