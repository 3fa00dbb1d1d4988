"""Where the orchestrator keeps what it can make again (unpacked FMUs, compiled calibration models): one folder
per kind under the user's cache, each movable or switched off by its own environment variable."""
from __future__ import annotations

import os
from pathlib import Path

__all__ = ["OFF_VALUES", "cache_folder"]

OFF_VALUES = ("", "off", "0", "none")


def cache_folder(env: str, kind: str) -> Path | None:
    """``$env`` (a folder; ``off``, ``0``, ``none`` or empty: None, no cache), else
    ``$XDG_CACHE_HOME/milling_twin/<kind>``, else ``~/.cache/milling_twin/<kind>``."""
    value = os.environ.get(env)
    if value is not None:
        return None if value.strip().lower() in OFF_VALUES else Path(value)
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "milling_twin" / kind
