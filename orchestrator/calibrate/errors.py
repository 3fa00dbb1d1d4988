"""The two ways a calibration stops: a bad spec (fails fast, naming file and key) or a failed fit."""
from __future__ import annotations

from pathlib import Path

__all__ = ["CalibrationError", "CalibrationSpecError"]


class CalibrationSpecError(ValueError):
    """An invalid calibration spec; the message starts with the spec file and the TOML key, e.g.
    ``scenarios/calibration/x.toml: [parameters."power.c9"]: unknown parameter ...``."""

    def __init__(self, path: Path | str, key: str, message: str) -> None:
        self.path, self.key, self.detail = Path(path), key, message
        super().__init__(f"{path}: {key}: {message}" if key else f"{path}: {message}")


class CalibrationError(RuntimeError):
    """The calibration could not produce an estimate (every start failed, a simulation failed, the
    FMU does not compute what models/ says); the message gives the cause."""
