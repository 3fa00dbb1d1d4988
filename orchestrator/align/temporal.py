"""One entry point for temporal alignment: choose a method by name; all return a TimeMap.

* ``"multiscale"`` (default, :mod:`milling_twin.orchestrator.align.multiscale`): the best method here.
* ``"patent"`` (:mod:`milling_twin.orchestrator.align.patent`): the process-simulation patent's method.
* ``"dtw"`` (:mod:`milling_twin.orchestrator.align.dtw_baseline`): plain dtaidistance DTW (baseline).

:func:`align_results` takes what the project produces: a recording (:class:`RecordedData`
with x, y, z position channels) and a co-simulation results table (``load_results``: a
``time`` column and the interpolator's x, y, z columns), with the output-delay convention of
:mod:`milling_twin.orchestrator.align.trajectory`.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import pandas as pd

from milling_twin.orchestrator.align.dtw_baseline import DtwOptions, align_dtw
from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.align.multiscale import MultiscaleOptions, align_multiscale
from milling_twin.orchestrator.align.patent import PatentOptions, align_patent
from milling_twin.orchestrator.align.timemap import TimeMap
from milling_twin.orchestrator.align.trajectory import Trajectory
from milling_twin.orchestrator.recorded import RecordedData

__all__ = ["METHODS", "align", "align_results"]

#: method name -> (function, options class)
METHODS: dict[str, tuple[Callable[..., TimeMap], type]] = {
    "multiscale": (align_multiscale, MultiscaleOptions),
    "patent": (align_patent, PatentOptions),
    "dtw": (align_dtw, DtwOptions),
}


def align(recorded: Trajectory, simulated: Trajectory, method: str = "multiscale",
          options: Any | None = None) -> TimeMap:
    """Map every recorded sample to its simulated time with ``method``; ``options`` is that
    method's options dataclass (default options if None)."""
    if method not in METHODS:
        raise AlignmentError(f"unknown alignment method {method!r}; methods: {sorted(METHODS)}")
    function, options_type = METHODS[method]
    if options is None:
        options = options_type()
    elif not isinstance(options, options_type):
        raise AlignmentError(f"method {method!r} takes {options_type.__name__}, got "
                             f"{type(options).__name__}")
    return function(recorded, simulated, options)


def align_results(recorded: RecordedData, results: pd.DataFrame,
                  simulated_columns: Sequence[str],
                  recorded_channels: Sequence[str] = ("x", "y", "z"),
                  method: str = "multiscale", options: Any | None = None,
                  output_delay: float = 0.0) -> TimeMap:
    """Align a recording with a co-simulation run (e.g. the interpolator's simulated tool
    positions ``["interp.x", "interp.y", "interp.z"]``). Both sides in the same unit (the
    project keeps SI metres in both)."""
    rec = Trajectory.from_recorded(recorded, recorded_channels)
    sim = Trajectory.from_results(results, simulated_columns, output_delay)
    return align(rec, sim, method, options)
