"""One calibration from its spec file: dispatch on the kind, then write the report."""
from __future__ import annotations

import time
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

from milling_twin.orchestrator.calibrate.report import write_report
from milling_twin.orchestrator.calibrate.result import CalibrationResult
from milling_twin.orchestrator.calibrate.spec import CalibrationSpec, load_spec
from milling_twin.orchestrator.results import RunFolder

__all__ = ["calibrate"]

Override = float | tuple[float, str] | Mapping[str, object]


def calibrate(spec_path: str | Path, fmu_dir: str | Path, out: str | Path = "runs", *, data: str | Path | None = None,
              progress: bool = True, write_set: str | Path | None = None,
              overrides: Mapping[str, Override] | None = None, workers: int | None = None,
              scheduler: str | None = None) -> CalibrationResult:
    """Run the calibration of ``spec_path``; results, report and the parameter set go to
    ``out/calibration/<name>/`` (the set under the file name of the spec's ``parameter_set``), and nothing
    is written outside ``out`` unless ``write_set`` is given: the set is then also published there (e.g.
    the spec's own ``parameter_set``, the committed file a calibrated scenario applies by name), after the
    re-simulation succeeded. ``overrides``: ``{"instance.variable": value}`` applied to the scenario before
    the fit, as a parameter set's values are (SI, or ``(value, unit)`` / ``{"value": v, "unit": u}``); the
    calibrated values win over them in the re-simulation.
    ``data``: the slot-milling recordings' folder (kind "slot_forces"; default as the validation finds it), or
    the runs' folder (kind "runs"; default its ``[runs].folder``). ``workers`` / ``scheduler``: instead of the
    spec's ``[solver]`` ones, where a kind "scenario" fit runs its simulations
    (:mod:`milling_twin.orchestrator.calibrate.parallel`; 0: serial, in this process)."""
    spec = load_spec(spec_path)
    if workers is not None or scheduler is not None:  # both replace the spec's
        if (workers is not None and workers < 0) or (workers and scheduler is not None):
            raise ValueError(f"workers={workers!r}, scheduler={scheduler!r}: expected workers >= 0 (0: serial, in "
                             "this process) or a scheduler, not both")
        spec = replace(spec, solver=replace(spec.solver, workers=workers or 0, scheduler=scheduler))
    out_dir = Path(out) / "calibration" / spec.name
    with RunFolder.claim(out_dir, what="calibration"):  # one calibration per folder at a time
        return _calibrate(spec, Path(fmu_dir), out_dir, data, progress, write_set, overrides)


def _calibrate(spec: CalibrationSpec, fmu_dir: Path, out_dir: Path, data: str | Path | None, progress: bool,
               write_set: str | Path | None, overrides: Mapping[str, Override] | None) -> CalibrationResult:
    values = {key: ({"value": value[0], "unit": value[1]} if isinstance(value, tuple) else value)
              for key, value in (overrides or {}).items()}
    publish = Path(write_set) if write_set is not None else None
    if spec.kind == "slot_forces":
        from milling_twin.orchestrator.calibrate.slot_forces import calibrate_slot_forces
        result = calibrate_slot_forces(spec, Path(fmu_dir), out_dir, data, progress, write_set=publish,
                                       overrides=values)
    elif spec.kind == "runs":
        from milling_twin.orchestrator.calibrate.runs_fit import calibrate_runs
        result = calibrate_runs(spec, Path(fmu_dir), out_dir, data, progress, write_set=publish, overrides=values)
    else:
        from milling_twin.orchestrator.calibrate.scenario_fit import calibrate_scenario
        result = calibrate_scenario(spec, Path(fmu_dir), out_dir, progress, write_set=publish, overrides=values)
    t0 = time.perf_counter()
    write_report(result)
    result.timings["report"] = time.perf_counter() - t0
    return result
