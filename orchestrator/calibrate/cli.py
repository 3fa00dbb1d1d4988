"""``python -m milling_twin.orchestrator calibrate SPEC [--fmu-dir DIR] [--out DIR] [--data DIR] [--no-progress]``.

Exit codes: 0 calibrated, 1 the calibration failed (every start failed, a simulation failed, FMU and
models/ disagree), 2 invalid spec, scenario or data.
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from milling_twin.models.units import UnitError
from milling_twin.orchestrator.calibrate.errors import CalibrationError, CalibrationSpecError
from milling_twin.orchestrator.recorded import RecordedDataError
from milling_twin.orchestrator.scenario import ScenarioError

__all__ = ["add_parser", "main"]

FMU_DIR_ENV = "MILLING_TWIN_FMU_DIR"


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("calibrate", help="fit model parameters to recorded data (a calibration spec)",
                       description="Calibrate: simulate, align with the recorded data, fit, write the parameter set, "
                                   "re-simulate and write the report (HTML and Markdown).")
    p.add_argument("spec", type=Path, help="calibration spec TOML file (format: orchestrator/calibrate/spec.py)")
    p.add_argument("--fmu-dir", type=Path, default=Path(os.environ.get(FMU_DIR_ENV, "build/fmus")),
                   help=f"folder of the built FMUs (default: ${FMU_DIR_ENV} or build/fmus)")
    p.add_argument("--out", type=Path, default=Path("runs"),
                   help="report and runs go to OUT/calibration/<name>/ (default: runs)")
    p.add_argument("--data", type=Path, default=None,
                   help="slot-milling recordings (kind slot_forces; default $MILLING_TWIN_SLOT_DATA or "
                        "../shared/data/slot_milling_forces)")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def main(args: argparse.Namespace) -> int:
    from milling_twin.orchestrator.calibrate.report import summary_lines
    from milling_twin.orchestrator.calibrate.run import calibrate
    from milling_twin.datasets import DataMissing

    try:
        result = calibrate(args.spec, args.fmu_dir, args.out, data=args.data, progress=not args.no_progress)
    except (CalibrationSpecError, ScenarioError, RecordedDataError, UnitError, DataMissing) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except CalibrationError as exc:
        print(f"error: calibration failed: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return 130
    print("stages: " + ", ".join(f"{name} {seconds:.2f} s" for name, seconds in result.timings.items()))
    print("\n".join(summary_lines(result)))
    print(f"parameter set: {result.parameter_set}")
    print(f"report: {result.report_html} (and {result.report_md.name})")
    return 0
