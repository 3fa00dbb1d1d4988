"""One calibration from its spec file: dispatch on the kind, then write the report."""
from __future__ import annotations

import time
from pathlib import Path

from milling_twin.orchestrator.calibrate.report import write_report
from milling_twin.orchestrator.calibrate.result import CalibrationResult
from milling_twin.orchestrator.calibrate.spec import load_spec

__all__ = ["calibrate"]


def calibrate(spec_path: str | Path, fmu_dir: str | Path, out: str | Path = "runs", *, data: str | Path | None = None,
              progress: bool = True) -> CalibrationResult:
    """Run the calibration of ``spec_path``; results and report go to ``out/calibration/<name>/``.
    ``data``: the slot-milling recordings' folder (kind "slot_forces"; default as the validation finds it)."""
    spec = load_spec(spec_path)
    out_dir = Path(out) / "calibration" / spec.name
    out_dir.mkdir(parents=True, exist_ok=True)
    if spec.kind == "slot_forces":
        from milling_twin.orchestrator.calibrate.slot_forces import calibrate_slot_forces
        result = calibrate_slot_forces(spec, Path(fmu_dir), out_dir, data, progress)
    else:
        from milling_twin.orchestrator.calibrate.scenario_fit import calibrate_scenario
        result = calibrate_scenario(spec, Path(fmu_dir), out_dir, progress)
    t0 = time.perf_counter()
    write_report(result)
    result.timings["report"] = time.perf_counter() - t0
    return result
