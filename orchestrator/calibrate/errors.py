"""The two ways a calibration stops: a bad spec (fails fast, naming file and key) or a failed fit."""
from __future__ import annotations

from milling_twin.orchestrator.toml_access import FileKeyError

__all__ = ["CalibrationError", "CalibrationSpecError"]


class CalibrationSpecError(FileKeyError):
    """An invalid calibration spec; the message starts with the spec file and the TOML key, e.g.
    ``scenarios/calibration/x.toml: [parameters."power.c9"]: unknown parameter ...``."""


class CalibrationError(RuntimeError):
    """The calibration could not produce an estimate (every start failed, a simulation failed, the
    FMU does not compute what models/ says); the message gives the cause."""
