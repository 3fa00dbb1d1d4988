"""The step clock of the force FMUs (``fmus/common/step_clock.h``, CuttingForce and ForceNet): the time since the
start of a run that they advance their spindle angle and displacement history by, independent of how the
importer does its time arithmetic.

Importers hand ``doStep`` the same steps in different floating-point forms: a step ``h`` from ``t_n = n h``,
from ``t += h``, or the difference ``t_(n+1) - t_n`` of two communication points, which differs from ``h`` in
its last bits. A model that accumulates the step sizes it is given (the spindle angle, ``angle += omega h``)
then differs in its last bits too, and where an output is discontinuous in the angle (an edge element entering
the cut exactly at the window's edge, the network's angle feature at 2 pi) that difference is a jump.

The clock counts whole nanoseconds, and the rest of every step apart: a step that is a whole number ``k`` of
nanoseconds up to 16 ulps of the importer's time (``|h - k ns| <= 16 eps (|t| + h)``, at most 1 ps) is taken
as the double nearest ``k ns`` (``k / 1e9``), so the same steps give the same angle and the same history
whatever the form; any other step (below 1 ns, 1/3 ms, ...) is taken as given, the clock keeping its part
beyond whole nanoseconds exactly, so its time does not drift from the sum of the steps. Same operations in
the same order as the C code; the tests hold the two equal.
"""
from __future__ import annotations

import math
import sys

NS_PER_S = 1e9
SNAP_ULPS = 16.0        # a step within this many ulps of the importer's time of whole nanoseconds is whole
SNAP_LIMIT = 1e-12      # ... and never more than 1 ps off them
MAX_NS = 2.0 ** 52      # whole nanoseconds counted exactly (52 days); beyond, steps are taken as given


class StepClock:
    """``ns`` whole nanoseconds (an integer-valued double) and ``rest`` seconds (below half a nanosecond)."""

    def __init__(self) -> None:
        self.ns = 0.0
        self.rest = 0.0

    def advance(self, time: float, h: float) -> float:
        """One step of ``h`` from the importer's communication point ``time``; returns the step the model takes."""
        scaled = h * NS_PER_S
        whole = float(math.floor(scaled + 0.5)) if scaled < MAX_NS else 0.0
        if whole >= 1.0 and whole + self.ns < MAX_NS:
            residual = h - whole / NS_PER_S
            if abs(residual) <= min(SNAP_ULPS * sys.float_info.epsilon * (abs(time) + h), SNAP_LIMIT):
                residual = 0.0
            self.ns += whole
        else:
            whole, residual = 0.0, h
        self.rest += residual
        if abs(self.rest) < 1.0:
            carry = float(math.floor(self.rest * NS_PER_S + 0.5))
            if carry != 0.0 and self.ns + carry < MAX_NS:
                self.ns += carry
                self.rest -= carry / NS_PER_S
        return whole / NS_PER_S if residual == 0.0 else h

    def seconds(self) -> float:
        """The time since the start [s]."""
        return self.ns / NS_PER_S + self.rest
