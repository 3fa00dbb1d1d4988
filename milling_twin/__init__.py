"""Milling twin: FMUs of CNC milling co-simulated against recorded machine data, aligned and calibrated.

The Python API (:mod:`milling_twin.api`): :func:`simulate`, :func:`calibrate`, :func:`load_results`,
:func:`load_scenario`, :func:`sweep` (studies), :class:`Results`. The command line: ``milling-twin``
(:mod:`milling_twin.cli`).
Subpackages: ``milling_twin.models`` (the equations, the single source of every FMU),
``milling_twin.orchestrator`` (scenarios, co-simulation, alignment, calibration, validation),
``milling_twin.training`` (the learned model parts), ``milling_twin.datasets`` (published data sets).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

if TYPE_CHECKING:
    from milling_twin.api import Results, calibrate, load_results, load_scenario, optimize, simulate, sweep

__all__ = ["Results", "__version__", "calibrate", "load_results", "load_scenario", "optimize", "simulate",
           "sweep"]


def __getattr__(name: str) -> Any:
    # the API loads on first use: `milling-twin --help` and `import milling_twin.models.units` stay light
    if name in __all__:
        from milling_twin import api

        return getattr(api, name)
    raise AttributeError(f"module 'milling_twin' has no attribute {name!r}")
