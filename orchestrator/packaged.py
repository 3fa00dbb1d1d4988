"""The FMUs and the stepper library that an installed wheel carries inside the package: ``milling_twin/fmus/`` and
``milling_twin/stepper/`` (put there by the wheel's build step, ``setup.py``; docs/packaging.md). A source checkout
and its editable install have neither: their FMUs and library are in ``build/``."""
from __future__ import annotations

from pathlib import Path

import milling_twin

__all__ = ["packaged_file", "packaged_fmu_dir"]


def _package_dir() -> Path:
    return Path(milling_twin.__file__).resolve().parent


def packaged_fmu_dir() -> Path | None:
    """``milling_twin/fmus/`` of the installed package when it holds FMUs, else None."""
    folder = _package_dir() / "fmus"
    return folder if folder.is_dir() and any(folder.glob("*.fmu")) else None


def packaged_file(folder: str, name: str) -> Path | None:
    """``milling_twin/<folder>/<name>`` of the installed package when it exists, else None."""
    path = _package_dir() / folder / name
    return path if path.is_file() else None
