"""A study reduction that kills the worker process running it (SIGKILL, as the OOM killer or a crashing FMU would):
once per case (a marker file says it happened) or, for the cases of ``always_depth``, every time."""
from __future__ import annotations

import os
import signal
from pathlib import Path

from milling_twin.orchestrator.study.reduce import CaseRun


def kill_worker(case: CaseRun, *, markers: str, always_depth: float = -1.0) -> dict[str, float]:
    depth = case.scenario.instance("force").inputs["axial_depth"]
    marker = Path(markers) / case.case_id
    attempts = int(marker.read_text()) + 1 if marker.is_file() else 1
    marker.write_text(str(attempts))
    if attempts == 1 or abs(depth - always_depth) < 1e-12:
        os.kill(os.getpid(), signal.SIGKILL)
    return {"attempts": float(attempts)}
