"""Alignment of recorded machine data with simulation, in time and in space.

Temporal (simulation-to-machine data registration): :func:`align` maps every recorded sample
to the simulated moment of the same machining state, by one of :data:`METHODS` (``multiscale``,
the patent's ``patent`` method, the ``dtw`` baseline), returning a :class:`TimeMap`.

Spatial (wall-thickness compensation by work-offset shift): :func:`compensate_wall` registers
the design target surface to the measured part and computes the work offset, with the G-code
to apply it.

Command line: ``milling-twin align temporal|spatial ...`` (handlers in :mod:`milling_twin.orchestrator.align.cli`).
"""
from milling_twin.orchestrator.align.errors import AlignmentError
from milling_twin.orchestrator.align.spatial import (Compensation, ProbeData, compensate_wall,
                                        work_offset_gcode)
from milling_twin.orchestrator.align.temporal import METHODS, align, align_results
from milling_twin.orchestrator.align.timemap import PathResidual, TimeMap, path_residual
from milling_twin.orchestrator.align.trajectory import Trajectory

__all__ = ["METHODS", "AlignmentError", "Compensation", "PathResidual", "ProbeData", "TimeMap",
           "Trajectory", "align", "align_results", "compensate_wall", "path_residual",
           "work_offset_gcode"]
