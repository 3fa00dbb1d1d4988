"""Schedule: look-ahead over the whole program, jerk-limited S-curves between stations (nodes of zero
acceleration). Mirrors ``fmus/interpolator/feed_schedule.c`` (and ``feed_schedule.h``)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

from milling_twin.models.interpolator.parser import MOVE_DWELL, MOVE_RAPID
from milling_twin.models.interpolator.path import BIG, Path

BISECTIONS = 60
VIOLATION_TOLERANCE = 1e-9


def s_curve_time(dv: float, a: float, j: float) -> float:
    """Duration of a jerk-limited velocity change dv >= 0 with zero acceleration at both ends."""
    if dv >= a * a / j:
        return dv / a + a / j
    return 2.0 * math.sqrt(dv / j)


def s_curve_phases(dv: float, a: float, j: float) -> tuple[float, float]:
    """(t1, t2) of a jerk-limited velocity change dv >= 0: each jerk phase lasts t1, the constant-acceleration
    phase between them t2 (0 when the acceleration limit is not reached)."""
    if dv >= a * a / j:
        return a / j, dv / a - a / j
    return math.sqrt(dv / j), 0.0


def s_curve_distance(v0: float, v1: float, a: float, j: float) -> float:
    return 0.5 * (v0 + v1) * s_curve_time(abs(v1 - v0), a, j)


def reach_up(v0: float, length: float, a: float, j: float) -> float:
    """Highest velocity reachable from v0 (zero acceleration) over length (zero acceleration at the end)."""
    if length <= 0.0:
        return v0
    p = 2.0 * v0
    q = length * math.sqrt(j)
    if p == 0.0:
        y = math.cbrt(q)
    else:
        y = 2.0 * math.sqrt(p / 3.0) * math.sinh(math.asinh(1.5 * q / p * math.sqrt(3.0 / p)) / 3.0)
    x = y * y
    if x >= a * a / j:
        qa = 0.5 / a
        qb = v0 / a + 0.5 * a / j
        qc = v0 * a / j - length
        x = -2.0 * qc / (qb + math.sqrt(qb * qb - 4.0 * qa * qc))
    return v0 + x


def _bisect_fitting(fits: Callable[[float], bool], good: float, bad: float) -> float:
    """Narrow [good, bad] (fits(good) holds, fits(bad) does not, fits changes once between them) by
    BISECTIONS halvings and return the end that fits."""
    for _ in range(BISECTIONS):
        mid = 0.5 * (good + bad)
        if fits(mid):
            good = mid
        else:
            bad = mid
    return good


def lowest_feasible(v_high: float, v_low: float, length: float, a: float, j: float) -> float:
    """The lowest velocity in [v_low, v_high] to which one can slow down from v_high over length."""
    if s_curve_distance(v_low, v_high, a, j) <= length:
        return v_low
    return _bisect_fitting(lambda v: s_curve_distance(v, v_high, a, j) <= length, v_high, v_low)


def segment_peak(va: float, vb: float, length: float, cap: float, a: float, j: float) -> float:
    """Cruise velocity of a segment va -> vp -> vb of the given length: the highest up to cap when cap is
    above both ends, else the lowest from cap up (the segment starts or ends above its cap)."""

    def fits(peak: float) -> bool:
        return s_curve_distance(va, peak, a, j) + s_curve_distance(peak, vb, a, j) <= length

    top = max(va, vb)
    if cap >= top:
        return cap if fits(cap) else _bisect_fitting(fits, top, cap)
    floor = max(cap, 0.0)
    return floor if fits(floor) else _bisect_fitting(fits, top, floor)


def s_curve_position(v0: float, v1: float, a: float, j: float, w: float) -> float:
    """Distance from the start of the S-curve v0 -> v1 at which the velocity is w (between v0 and v1)."""
    dv = abs(v1 - v0)
    if dv <= 0.0:
        return 0.0
    t1, t2 = s_curve_phases(dv, a, j)
    total = 2.0 * t1 + t2
    delta = abs(w - v0)
    d1 = 0.5 * j * t1 * t1
    if delta <= d1:
        t = math.sqrt(2.0 * delta / j)
        dx = j * t * t * t / 6.0
    elif delta <= d1 + j * t1 * t2:
        tau = (delta - d1) / (j * t1)
        t = t1 + tau
        dx = j * t1 * t1 * t1 / 6.0 + d1 * tau + 0.5 * j * t1 * tau * tau
    else:
        r = math.sqrt(2.0 * max(dv - delta, 0.0) / j)
        t = total - r
        dx = 0.5 * dv * total - (dv * r - j * r * r * r / 6.0)
    return v0 * t + dx if v1 >= v0 else v0 * t - dx


@dataclass
class Segment:
    s0: float
    length: float
    va: float
    vp: float
    vb: float
    a: float
    j: float
    cap: float
    soft_cap: float
    first: int      # first interval
    last: int       # last interval (inclusive)


@dataclass
class Piece:
    t: float
    s: float
    v: float
    a: float
    j: float


class Schedule:
    """Stations (nodes with zero acceleration), their velocities and the S-curve pieces in between."""

    def __init__(self, path: Path, max_feed: float, rapid_feed: float):
        self.path = path
        self.max_feed = max_feed
        self.rapid_feed = rapid_feed
        self.override = 1.0
        self.pieces: list[Piece] = []
        self.end_time = 0.0
        self.hold = False
        # the part of the path planned over: intervals 0..n_int - 1, ending at rest at s = end (the look-ahead
        # window of engine.py; the whole path unless plan() is given a window)
        self.n_int = len(path.int_move)
        self.end = path.total
        self.raised = False  # the last plan raised a station's velocity above its hard cap (the start too fast)

    def soft(self, move: int) -> float:
        if move < 0:
            return BIG
        m = self.path.program.moves[move]
        if m.kind == MOVE_RAPID:
            return self.rapid_feed
        return min(m.feed * self.override, self.max_feed)

    def dwell(self, move: int) -> float:
        """Seconds the tool stands in a dwell move (0 for the other moves)."""
        m = self.path.program.moves[move]
        return m.dwell if m.kind == MOVE_DWELL else 0.0

    def node_cap(self, k: int) -> float:
        path = self.path
        return min(path.node_vh[k], self.soft(path.node_left[k]), self.soft(path.node_right[k]))

    def interval_at(self, s: float) -> int:
        """Interval containing s (the last one whose start node is <= s)."""
        ns = self.path.node_s
        lo, hi = 0, len(ns) - 2
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if ns[mid] <= s:
                lo = mid
            else:
                hi = mid - 1
        return lo

    def segments(self, s_start: float, first_interval: int) -> list[Segment]:
        path = self.path
        out: list[Segment] = []
        n_int = self.n_int
        i = first_interval
        s0 = s_start
        while i < n_int:
            a = j = BIG
            cap = 0.0
            soft = BIG
            first = i
            while True:
                m = path.int_move[i]
                a = min(a, path.int_at[i])
                j = min(j, path.int_jt[i])
                sm = self.soft(m)
                soft = min(soft, sm)
                cap = max(cap, min(sm, path.int_cap[i]))
                i += 1
                if i >= n_int or path.station[i] or path.node_vh[i] == 0.0:  # at rest there: a station
                    break
            end = path.node_s[i] if i <= n_int else path.total
            out.append(Segment(s0, end - s0, 0.0, 0.0, 0.0, a, j, cap, soft, first, i - 1))
            s0 = end
        return out

    def velocities(self, segs: list[Segment], v_start: float) -> None:
        """Station velocities: backward envelope over every cap, then forward from v_start, raised
        where the start is above new (soft) caps and cannot slow down in time (``raised``: above a hard cap)."""
        path = self.path
        n = len(segs)
        caps = [0.0] * (n + 1)
        for k in range(1, n):
            caps[k] = self.node_cap(segs[k].first)
        caps[n] = 0.0
        b = [0.0] * (n + 1)
        for k in range(n - 1, 0, -1):
            b[k] = min(caps[k], reach_up(b[k + 1], segs[k].length, segs[k].a, segs[k].j))
        b[0] = BIG
        v = [0.0] * (n + 1)
        v[0] = v_start
        raised = False
        for k in range(1, n + 1):
            sg = segs[k - 1]
            vk = min(b[k], reach_up(v[k - 1], sg.length, sg.a, sg.j))
            # (within the rounding of reach_up: the distance of a jerk-limited slow-down without reaching the
            # acceleration limit is not monotonic in its end velocity, so a stop the backward pass found to fit
            # exactly, rejected by an ulp, would be raised to the far side of that hump, e.g. a block ending at 12
            # mm/s instead of at rest)
            if vk < v[k - 1] and s_curve_distance(vk, v[k - 1], sg.a, sg.j) > sg.length * (1.0 + VIOLATION_TOLERANCE):
                vk = lowest_feasible(v[k - 1], vk, sg.length, sg.a, sg.j)
            if vk > (path.node_vh[segs[k].first] if k < n else 0.0) * (1.0 + VIOLATION_TOLERANCE):
                raised = True
            v[k] = vk
        for k in range(n):
            segs[k].va = v[k]
            segs[k].vb = v[k + 1]
            segs[k].vp = segment_peak(v[k], v[k + 1], segs[k].length, segs[k].cap, segs[k].a, segs[k].j)
        self.raised = raised

    def violations(self, segs: list[Segment]) -> list[int]:
        """Nodes to make stations: per segment the violated node with the lowest cap, or the two ends of the
        interval holding a peak above that interval's cap."""
        path = self.path
        add: list[int] = []
        for sg in segs:
            hard_only = sg.va > sg.soft_cap * (1.0 + VIOLATION_TOLERANCE) or sg.vb > sg.soft_cap * (
                1.0 + VIOLATION_TOLERANCE)
            da = s_curve_distance(sg.va, sg.vp, sg.a, sg.j)
            db = s_curve_distance(sg.vp, sg.vb, sg.a, sg.j)
            cruise = sg.length - da - db
            worst, worst_cap = -1, BIG
            for k in range(sg.first + 1, sg.last + 1):
                allowed = path.node_vh[k] if hard_only else self.node_cap(k)
                w = allowed * (1.0 + VIOLATION_TOLERANCE)
                x = path.node_s[k] - sg.s0
                if x <= da:
                    if sg.vp >= sg.va:
                        bad = w < sg.va or (w < sg.vp and x > s_curve_position(sg.va, sg.vp, sg.a, sg.j, w))
                    else:
                        bad = w < sg.vp or (w < sg.va and x < s_curve_position(sg.va, sg.vp, sg.a, sg.j, w))
                elif x <= da + cruise:
                    bad = w < sg.vp
                else:
                    y = x - da - cruise
                    if sg.vb >= sg.vp:
                        bad = w < sg.vp or (w < sg.vb and y > s_curve_position(sg.vp, sg.vb, sg.a, sg.j, w))
                    else:
                        bad = w < sg.vb or (w < sg.vp and y < s_curve_position(sg.vp, sg.vb, sg.a, sg.j, w))
                if bad and allowed < worst_cap:
                    worst, worst_cap = k, allowed
            if worst >= 0:
                add.append(worst)
                continue
            if sg.vp > sg.va and sg.vp > sg.vb and sg.last > sg.first:
                # the peak region [da, da + cruise]: if no node lies in it, its interval's cap must hold
                lo_s, hi_s = sg.s0 + da, sg.s0 + da + cruise
                i = sg.first
                while i < sg.last and path.node_s[i + 1] <= lo_s:
                    i += 1
                if path.node_s[i + 1] >= hi_s or i == sg.last:
                    m = path.int_move[i]
                    cap = path.int_cap[i] if hard_only else min(self.soft(m), path.int_cap[i])
                    if sg.vp > cap * (1.0 + VIOLATION_TOLERANCE):
                        for node in (i, i + 1):
                            if not path.station[node]:
                                add.append(node)
        return add

    def plan(self, s_start: float, v_start: float, t_start: float, override: float,
             window_end: int | None = None) -> None:
        """Schedule from (s_start, v_start, zero acceleration) at t_start to the end of the program, or to node
        window_end, at rest there."""
        path = self.path
        self.n_int = len(path.int_move) if window_end is None else window_end
        self.end = path.total if window_end is None else path.node_s[window_end]
        self.override = override
        self.hold = False
        self.raised = False
        if not path.int_move:
            self.pieces = [Piece(t_start, s_start, 0.0, 0.0, 0.0)]
            self.end_time = t_start
            return
        first = self.interval_at(s_start)
        while True:
            segs = self.segments(s_start, first)
            self.velocities(segs, v_start)
            add = self.violations(segs)
            if not add:
                break
            for node in add:
                path.station[node] = 1
        self.pieces = self.make_pieces(segs, t_start)

    def make_pieces(self, segs: list[Segment], t: float) -> list[Piece]:
        pieces: list[Piece] = []
        for sg in segs:
            s = sg.s0
            if sg.length <= 0.0:
                dwell = self.dwell(self.path.int_move[sg.first])
                if dwell > 0.0:  # a piece at rest (the only one with zero v, a and j before the end)
                    pieces.append(Piece(t, s, 0.0, 0.0, 0.0))
                    t += dwell
                continue
            da = s_curve_distance(sg.va, sg.vp, sg.a, sg.j)
            db = s_curve_distance(sg.vp, sg.vb, sg.a, sg.j)
            cruise = max(sg.length - da - db, 0.0)
            t, s = _s_curve_pieces(pieces, t, s, sg.va, sg.vp, sg.a, sg.j)
            if cruise > 0.0:
                if sg.vp <= 0.0:
                    pieces.append(Piece(t, s, 0.0, 0.0, 0.0))
                    self.hold = True
                    self.end_time = math.inf
                    return pieces
                pieces.append(Piece(t, s, sg.vp, 0.0, 0.0))
                t += cruise / sg.vp
                s += cruise
            t, s = _s_curve_pieces(pieces, t, s, sg.vp, sg.vb, sg.a, sg.j)
        pieces.append(Piece(t, self.end, 0.0, 0.0, 0.0))
        self.end_time = t
        return pieces


def _s_curve_pieces(pieces: list[Piece], t: float, s: float, v0: float, v1: float, a: float,
                    j: float) -> tuple[float, float]:
    dv = v1 - v0
    if dv == 0.0:
        return t, s
    sign = 1.0 if dv > 0.0 else -1.0
    dv = abs(dv)
    t1, t2 = s_curve_phases(dv, a, j)
    jerk = sign * j
    am = jerk * t1
    v = v0
    # phase 1
    pieces.append(Piece(t, s, v, 0.0, jerk))
    s += v * t1 + jerk * t1 * t1 * t1 / 6.0
    v += 0.5 * jerk * t1 * t1
    t += t1
    if t2 > 0.0:
        pieces.append(Piece(t, s, v, am, 0.0))
        s += v * t2 + 0.5 * am * t2 * t2
        v += am * t2
        t += t2
    pieces.append(Piece(t, s, v, am, -jerk))
    s += v * t1 + 0.5 * am * t1 * t1 - jerk * t1 * t1 * t1 / 6.0
    t += t1
    return t, s
