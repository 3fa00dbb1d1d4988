"""Calibration that closes the loop: fit model parameters (the models/ casadi expressions, the same
equations the FMUs are generated from, or, where those cannot give the outputs, the FMUs themselves with
finite differences) to aligned recorded data, report, and write a parameter set the scenarios apply by name.

``milling-twin calibrate SPEC``; spec format in
:mod:`milling_twin.orchestrator.calibrate.spec`; the generic kind in :mod:`milling_twin.orchestrator.calibrate.scenario_fit`,
the slot-milling forces in :mod:`milling_twin.orchestrator.calibrate.slot_forces`. Importing the package is light
(no casadi, no matplotlib) so that the orchestrator's command line starts fast.
"""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from milling_twin.orchestrator.calibrate.errors import CalibrationError, CalibrationSpecError
from milling_twin.orchestrator.calibrate.spec import CalibrationSpec, load_spec

if TYPE_CHECKING:
    from milling_twin.orchestrator.calibrate.result import CalibrationResult

__all__ = ["CalibrationError", "CalibrationSpec", "CalibrationSpecError", "calibrate", "load_spec"]


def calibrate(spec_path: str | Path, fmu_dir: str | Path, out: str | Path = "runs", *,
              data: str | Path | None = None, progress: bool = True, write_set: str | Path | None = None,
              overrides: Mapping[str, Any] | None = None, workers: int | None = None,
              scheduler: str | None = None) -> "CalibrationResult":
    """See :func:`milling_twin.orchestrator.calibrate.run.calibrate`."""
    from milling_twin.orchestrator.calibrate.run import calibrate as run_calibration
    return run_calibration(spec_path, fmu_dir, out, data=data, progress=progress, write_set=write_set,
                           overrides=overrides, workers=workers, scheduler=scheduler)
