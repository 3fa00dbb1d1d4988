"""Path: the program as the feedrate schedule sees it (moves laid end to end along the arc length s, adaptive
NURBS samples, nodes with their hard speed caps, intervals with their tangential limits). Mirrors
``fmus/interpolator/path.c`` (and ``path.h``)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Mapping, Sequence

from milling_twin.models.interpolator.nurbs import Nurbs, arc_length_derivatives, gauss_length
from milling_twin.models.interpolator.nurbs import dot as _dot
from milling_twin.models.interpolator.parser import (MOVE_ARC, MOVE_DWELL, MOVE_LINE, MOVE_NURBS, MOVE_RAPID, Move,
                                                    Program, line_error)

COS_TURN = math.cos(0.02)            # NURBS sampling: tangent turn between neighbouring samples
CURVATURE_VARIATION = 0.02           # and relative curvature change (where the turn is significant)
SIGNIFICANT_TURN = 1e-3
MAX_SAMPLE_DEPTH = 40
MAX_SAMPLES = 2_000_000
INITIAL_SUBDIVISION = 4
CHORD_SAFETY = 0.95                   # the chord limit uses 95 % of chord_error (sampling margin)
TANGENT_TOLERANCE = 1e-12             # 1 - cos(angle) below which a junction is tangent
BIG = 1e300
# NURBS: the lowest share of its other limits the speed gives to the coupling of acceleration and curvature (below
# it the acceleration gives way). 0.5 while the coupling had a fixed third of the axis jerk; with the budget it has
# now (coupled_acceleration) 0.75 measured best: Bezier hairpins 1/0.1/0.01 mm from a cusp +9.7/+9.1/+9.9 % over the
# checker's bound (0.5: +11.5/+10.4/+10.7; 0.65, 0.7, 0.8, 0.85 each leave one at +10.2 to +12.5 %), 504 random
# curves 2.5 % faster on average (tight ones 12 %), none slower by more than 0.8 %, every limit held
COUPLING_SPEED_SHARE = 0.75


@dataclass
class Limits:
    period: float
    acceleration: float
    jerk: float
    centripetal: float
    chord: float
    axis_acceleration: tuple[float, float, float]
    axis_jerk: tuple[float, float, float]
    max_feed: float


def limits_of(p: Mapping[str, float]) -> Limits:
    return Limits(p["period"], p["acceleration"], p["jerk"], p["centripetal_acceleration"], p["chord_error"],
                  tuple(p[f"axis_acceleration_{a}"] for a in "xyz"), tuple(p[f"axis_jerk_{a}"] for a in "xyz"),
                  max(p["max_feed"], p["rapid_feed"]))


def tangential_limits(lim: Limits, t: Sequence[float], curved: bool) -> tuple[float, float]:
    """Tangential acceleration and jerk limits where the unit tangent is t: the path limits, and each axis's
    share of its own limit (all of it on straight moves; on curves 1/2 of the acceleration, the rest is
    for the centripetal part, and 1/3 of the jerk, the rest for the curvature terms)."""
    at, jt = lim.acceleration, lim.jerk
    share_a = 0.5 if curved else 1.0
    share_j = (1.0 / 3.0) if curved else 1.0
    for i in range(3):
        ti = abs(t[i])
        if ti > 0.0:
            at = min(at, share_a * lim.axis_acceleration[i] / ti)
            jt = min(jt, share_j * lim.axis_jerk[i] / ti)
    return at, jt


def curvature_limit(lim: Limits, kappa: float, k: Sequence[float], kp: Sequence[float], at: float) -> float:
    """Highest path speed allowed by the chord error, the centripetal acceleration, the curvature jerk
    and the axes' shares of acceleration and jerk, where the curvature is kappa, d2C/ds2 = k and
    d3C/ds3 = kp, with tangential acceleration limit at."""
    v = BIG
    if kappa > 0.0:
        rho = 1.0 / kappa
        delta = CHORD_SAFETY * lim.chord
        if delta < rho:
            v = min(v, 2.0 * math.sqrt(delta * (2.0 * rho - delta)) / lim.period)
        else:
            v = min(v, 2.0 * rho / lim.period)
        v = min(v, math.sqrt(lim.centripetal / kappa))
        v = min(v, math.cbrt(lim.jerk / (kappa * kappa)))
    for i in range(3):
        ki, kpi = abs(k[i]), abs(kp[i])
        if ki > 0.0:
            v = min(v, math.sqrt(0.5 * lim.axis_acceleration[i] / ki))
            if at > 0.0:  # at = 0: the caller bounds the tangential acceleration instead (coupled_acceleration)
                v = min(v, lim.axis_jerk[i] / (9.0 * at * ki))
        if kpi > 0.0:
            v = min(v, math.cbrt(lim.axis_jerk[i] / (3.0 * kpi)))
    return v


def coupled_acceleration(lim: Limits, t: Sequence[float], jt: float, k: Sequence[float], kp: Sequence[float], v: float,
                         at: float) -> float:
    """The tangential acceleration limit lowered so that the jerk of its coupling with the curvature, 3 v a |k_i|,
    stays within what each axis's jerk leaves over the tangential jerk's |t_i| jt and the curvature change's
    v^3 |k'_i| at the speed limit v (the axis jerk is t_i j + 3 k_i v a + k'_i v^3; at least the third that the
    speed limit leaves it, more where v is below the k' limit): near a cusp the curvature is huge and the speed
    tiny, and the acceleration, not the speed, gives way."""
    for i in range(3):
        ki = abs(k[i])
        if ki > 0.0 and v < BIG:
            budget = lim.axis_jerk[i] - abs(t[i]) * jt - v * v * v * abs(kp[i])
            at = min(at, budget / (3.0 * v * ki))
    return at


def junction_limit(lim: Limits, ta, ka, tb, kb) -> float:
    """Speed allowed where tangent ta / curvature vector ka (end of one move) meet tb / kb: a corner makes
    the velocity jump by v |tb - ta| within one period, a curvature change the acceleration by v^2 |kb - ka|."""
    v = BIG
    period = lim.period
    if _dot(ta, tb) < 1.0 - TANGENT_TOLERANCE:
        dt = [tb[i] - ta[i] for i in range(3)]
        norm = math.sqrt(_dot(dt, dt))
        v = min(v, lim.acceleration * period / norm, lim.jerk * period * period / norm)
        for i in range(3):
            di = abs(dt[i])
            if di > 0.0:
                v = min(v, 0.5 * lim.axis_acceleration[i] * period / di,
                        lim.axis_jerk[i] * period * period / (3.0 * di))
    dk = [kb[i] - ka[i] for i in range(3)]
    norm = math.sqrt(_dot(dk, dk))
    if norm > 0.0:
        v = min(v, math.sqrt(lim.jerk * period / norm))
        for i in range(3):
            di = abs(dk[i])
            if di > 0.0:
                v = min(v, math.sqrt(lim.axis_jerk[i] * period / (3.0 * di)))
    return v


@dataclass
class Geometry:
    """Tangent, curvature vector, its s-derivative and the limits at a point of a move."""

    t: list[float]
    k: list[float]
    kp: list[float]


def line_geometry(move: Move) -> tuple[list[float], float]:
    d = [move.end[i] - move.start[i] for i in range(3)]
    length = math.sqrt(_dot(d, d))
    return [d[i] / length for i in range(3)], length


class ArcShape:
    """Helical arc: centre c, plane axes (a, b, normal), angle theta0 + lam * sweep, radius r0..r1,
    normal coordinate c_n + lam * height; lam = s / length."""

    def __init__(self, move: Move):
        self.m = move
        rm = 0.5 * (move.r0 + move.r1)
        planar = rm * move.sweep
        self.length = math.sqrt(planar * planar + move.height * move.height)
        self.omega = abs(move.sweep) / self.length
        self.rm = rm

    def point(self, lam: float) -> list[float]:
        m = self.m
        if lam >= 1.0:
            return list(m.end)
        theta = m.theta0 + lam * m.sweep
        r = m.r0 + lam * (m.r1 - m.r0)
        ia, ib, inormal = m.axes
        p = [0.0, 0.0, 0.0]
        p[ia] = m.center[ia] + r * math.cos(theta)
        p[ib] = m.center[ib] + r * math.sin(theta)
        p[inormal] = m.center[inormal] + lam * m.height
        return p

    def tangent(self, lam: float) -> list[float]:
        m = self.m
        theta = m.theta0 + lam * m.sweep
        r = m.r0 + lam * (m.r1 - m.r0)
        c, s = math.cos(theta), math.sin(theta)
        ia, ib, inormal = m.axes
        d = [0.0, 0.0, 0.0]
        d[ia] = -r * s * m.sweep + (m.r1 - m.r0) * c
        d[ib] = r * c * m.sweep + (m.r1 - m.r0) * s
        d[inormal] = m.height
        norm = math.sqrt(_dot(d, d))
        return [d[i] / norm for i in range(3)]

    def geometry_bound(self) -> Geometry:
        """Per-axis magnitudes bounding |T_i|, |k_i|, |k'_i| over the whole arc (in-plane axes: the circle's
        extremes; normal axis: the helix's constant climb)."""
        m = self.m
        ia, ib, inormal = m.axes
        rw = self.rm * self.omega
        t, k, kp = [0.0] * 3, [0.0] * 3, [0.0] * 3
        for i in (ia, ib):
            t[i] = min(1.0, rw)
            k[i] = rw * self.omega
            kp[i] = rw * self.omega * self.omega
        t[inormal] = abs(m.height) / self.length
        return Geometry(t, k, kp)

    def end_geometry(self, lam: float) -> Geometry:
        """Tangent and curvature vector at lam (for junctions; helix: k = -r w^2 (cos, sin) in the plane)."""
        m = self.m
        theta = m.theta0 + lam * m.sweep
        ia, ib, inormal = m.axes
        t = self.tangent(lam)
        w2 = self.omega * self.omega
        r = m.r0 + lam * (m.r1 - m.r0)
        k = [0.0, 0.0, 0.0]
        k[ia] = -r * w2 * math.cos(theta)
        k[ib] = -r * w2 * math.sin(theta)
        return Geometry(t, k, [0.0, 0.0, 0.0])


@dataclass
class Path:
    """The program as the schedule sees it: moves with their start s and length, and nodes along s.

    Node k: position s, hard speed cap vh (geometry and dynamics), the moves left and right of it (-1 at
    the ends; equal inside a move), station flag. Interval k (node k to k+1): its move, tangential limits
    and the hard cap of its interior (a peak between the two nodes)."""

    program: Program
    lim: Limits
    move_s: list[float]
    move_length: list[float]
    move_cap: list[float]           # constant hard cap of lines/arcs (BIG for lines)
    move_span: list[tuple[int, int]]
    curves: list[Nurbs]
    arcs: dict[int, ArcShape]
    node_s: list[float] = field(default_factory=list)
    node_vh: list[float] = field(default_factory=list)
    node_left: list[int] = field(default_factory=list)
    node_right: list[int] = field(default_factory=list)
    station: list[int] = field(default_factory=list)
    int_move: list[int] = field(default_factory=list)
    int_at: list[float] = field(default_factory=list)
    int_jt: list[float] = field(default_factory=list)
    int_cap: list[float] = field(default_factory=list)
    total: float = 0.0


class PathError(ValueError):
    pass


def _nurbs_samples(curve: Nurbs, lim: Limits, u0: float, u1: float, lo: int, hi: int, line: int, file: str,
                   text: str | None = None):
    """Adaptive samples of one NURBS move: lists (u, s, vlc, at, jt, geometry at the ends)."""
    us: list[float] = []
    ss: list[float] = []
    vl: list[float] = []
    ats: list[float] = []
    jts: list[float] = []
    first_geometry = last_geometry = None

    def refusal(expected: str) -> str:
        """The parser's format, quoting the block's line when the program text is known."""
        return line_error(text, file, line, expected) if text is not None else f"{file} line {line}: {expected}"

    def point(u: float):
        d = curve.evaluate(u, 3, lo, hi)
        g = math.sqrt(_dot(d[1], d[1]))
        kappa = kpp = math.inf  # (a zero tangent: arc_length_derivatives would divide by zero)
        if g > 0.0:
            g, t, k, kp, _, _ = arc_length_derivatives(d)
            kappa = math.sqrt(_dot(k, k))
            kpp = _dot(kp, kp)
        if not (g > 0.0) or not math.isfinite(g) or not math.isfinite(kappa) or not math.isfinite(kpp):
            raise PathError(refusal(f"the NURBS block has a zero tangent or a singular point near u = {u:.9g} "
                                    "(repeated control points?)"))
        at, jt = tangential_limits(lim, t, True)
        # the speed gives way to the acceleration-curvature coupling down to half the other limits, then the
        # acceleration does (near a cusp)
        v = max(curvature_limit(lim, kappa, k, kp, at), COUPLING_SPEED_SHARE * curvature_limit(lim, kappa, k, kp, 0.0))
        at = coupled_acceleration(lim, t, jt, k, kp, v, at)
        return t, kappa, v, at, jt, d[0]

    def push(u: float, s: float, info, v: float) -> None:
        if len(us) >= MAX_SAMPLES:
            raise PathError(refusal(f"the NURBS block needs more than {MAX_SAMPLES} samples"))
        us.append(u)
        ss.append(s)
        vl.append(v)
        ats.append(info[3])
        jts.append(info[4])

    def refine(ua: float, ia, ub: float, ib, s_a: float, depth: int) -> float:
        """Samples in (ua, ub] (ua already pushed with s_a); returns s at ub."""
        um = 0.5 * (ua + ub)
        im = point(um)
        e = [ib[5][0] - ia[5][0], ib[5][1] - ia[5][1], ib[5][2] - ia[5][2]]
        chord = math.sqrt(_dot(e, e))
        kmax = max(ia[1], im[1], ib[1])
        kmin = min(ia[1], im[1], ib[1])
        split = (_dot(ia[0], im[0]) < COS_TURN or _dot(im[0], ib[0]) < COS_TURN
                 or (kmax * chord > SIGNIFICANT_TURN and kmax - kmin > CURVATURE_VARIATION * kmax))
        if split and depth < MAX_SAMPLE_DEPTH and um > ua and um < ub:
            s_m = refine(ua, ia, um, im, s_a, depth + 1)
            return refine(um, im, ub, ib, s_m, depth + 1)
        s_b = s_a + gauss_length(curve, ua, ub, lo, hi)
        push(ub, s_b, ib, interior_limit(ia[2], im[2], ib[2]))
        return s_b

    kn = curve.knots
    info0 = point(u0)
    push(u0, 0.0, info0, info0[2])
    s = 0.0
    for span in range(lo, hi + 1):
        a, b = max(kn[span], u0), min(kn[span + 1], u1)
        if not b > a:
            continue
        multiplicity = kn.count(a)
        if a > u0 and multiplicity >= curve.p - 1:
            # an inner knot of multiplicity m with p - m < 2: the curvature jumps there, a junction
            vl[-1] = min(vl[-1], knot_junction(curve, lim, a, span - multiplicity, span))
        ua, ia = a, (info0 if a == u0 else point(a))
        for j in range(1, INITIAL_SUBDIVISION + 1):
            ub = a + (b - a) * j / INITIAL_SUBDIVISION if j < INITIAL_SUBDIVISION else b
            ib = point(ub)
            s = refine(ua, ia, ub, ib, s, 0)
            ua, ia = ub, ib
    # geometry at both ends for the junctions (left-sided derivatives at u1: span hi)
    d0 = curve.evaluate(u0, 3, lo, lo)
    _, t0, k0, kp0, _, _ = arc_length_derivatives(d0)
    d1 = curve.evaluate(u1, 3, hi, hi)
    _, t1, k1, kp1, _, _ = arc_length_derivatives(d1)
    first_geometry = Geometry(t0, k0, kp0)
    last_geometry = Geometry(t1, k1, kp1)
    return us, ss, vl, ats, jts, first_geometry, last_geometry


def interior_limit(va: float, vm: float, vb: float) -> float:
    """The speed limit of a sample (limit vb) ending an interval from a sample with limit va whose midpoint's limit
    is vm: where vm is below both ends (a curvature peak between the samples) and the three differ by at most
    CURVATURE_VARIATION of vm (a resolved peak, between samples that the sampling left unsplit), the vertex of the
    parabola through them (it lies within the middle half; its dip below vm is at most 1/8 of the larger
    difference), else vb. The samples' limits alone missed such peaks: 1 % more curvature between two samples, +0.68
    % centripetal acceleration on a random quintic. Unresolved variations (a near cusp's tip, where the turn between
    samples is insignificant) keep their samples' limits: the midpoint there would slow a hairpin by 2 %."""
    if vm < va and vm < vb and va - vm <= CURVATURE_VARIATION * vm and vb - vm <= CURVATURE_VARIATION * vm:
        c = va + vb - 2.0 * vm
        return vm - (vb - va) * (vb - va) / (8.0 * c)
    return vb


def knot_junction(curve: Nurbs, lim: Limits, u: float, before: int, span: int) -> float:
    """The junction limit at the knot u that ends the span `before` and starts `span`: the tangent and curvature
    vector of the span before (left-sided derivatives) against those of the span after."""
    _, ta, ka, _, _, _ = arc_length_derivatives(curve.evaluate(u, 3, before, before))
    _, tb, kb, _, _, _ = arc_length_derivatives(curve.evaluate(u, 3, span, span))
    return junction_limit(lim, ta, ka, tb, kb)


def conservative_limits(ss: Sequence[float], vl: Sequence[float], lim: Limits) -> list[float]:
    """Each sample's limit lowered to the lowest of its neighbours and of every sample within the step the tool
    can take there (min(limit, max feed) * period): a step spans all of them, and its chord error and
    accelerations follow the sharpest point it spans; a sample at distance d binds only speeds above d / period
    (slower steps do not reach it: near a cusp the tip's tiny limit does not spread over its window)."""
    n = len(vl)
    vc = []
    for i in range(n):
        v = min(vl[max(0, i - 1)], vl[i], vl[min(n - 1, i + 1)])
        window = min(vl[i], lim.max_feed) * lim.period
        # a step spans sample j only at a speed above its distance / period: below that j does not bind
        j = i - 2
        while j >= 0 and ss[i] - ss[j] <= window:
            v = min(v, max(vl[j], (ss[i] - ss[j]) / lim.period))
            j -= 1
        j = i + 2
        while j < n and ss[j] - ss[i] <= window:
            v = min(v, max(vl[j], (ss[j] - ss[i]) / lim.period))
            j += 1
        vc.append(v)
    return vc


def build_path(program: Program, p: Mapping[str, float], text: str | None = None) -> Path:
    """The path of a parsed program; `text`, the program's text, lets a refusal quote its line."""
    lim = limits_of(p)
    curves = [Nurbs(c) for c in program.curves]
    path = Path(program, lim, [], [], [], [], curves, {})
    ends: list[tuple[Geometry, Geometry]] = []
    s = 0.0
    samples = []  # per move: list of (local s, vlc) for NURBS; None else
    for index, move in enumerate(program.moves):
        path.move_s.append(s)
        # the program's contour tolerance (G64 P, CYCLE832) is the chord error allowed on its moves
        move_lim = replace(lim, chord=move.tolerance) if move.tolerance > 0.0 else lim
        if move.kind in (MOVE_RAPID, MOVE_LINE):
            t, length = line_geometry(move)
            at, jt = tangential_limits(lim, t, False)
            zero = [0.0, 0.0, 0.0]
            geometry = Geometry(t, zero, zero)
            ends.append((geometry, geometry))
            path.move_cap.append(BIG)
            path.move_span.append((0, 0))
            samples.append(([0.0, length], [BIG, BIG], [at, at], [jt, jt]))
        elif move.kind == MOVE_DWELL:
            # no length: the path comes to rest on both of its nodes (stations), the schedule stands `dwell` there
            zero = [0.0, 0.0, 0.0]
            geometry = Geometry(zero, zero, zero)
            ends.append((geometry, geometry))
            length = 0.0
            path.move_cap.append(0.0)
            path.move_span.append((0, 0))
            samples.append(([0.0, 0.0], [0.0, 0.0], [lim.acceleration] * 2, [lim.jerk] * 2))
        elif move.kind == MOVE_ARC:
            arc = ArcShape(move)
            path.arcs[index] = arc
            length = arc.length
            bound = arc.geometry_bound()
            at, jt = tangential_limits(lim, bound.t, True)
            kappa = arc.rm * arc.omega * arc.omega
            v = curvature_limit(move_lim, kappa, bound.k, bound.kp, at)
            ends.append((arc.end_geometry(0.0), arc.end_geometry(1.0)))
            path.move_cap.append(v)
            path.move_span.append((0, 0))
            samples.append(([0.0, length], [v, v], [at, at], [jt, jt]))
        else:
            curve = curves[move.curve]
            lo, hi = curve.span_range(move.u0, move.u1)
            path.move_span.append((lo, hi))
            us, ss, vl, ats, jts, g0, g1 = _nurbs_samples(curve, move_lim, move.u0, move.u1, lo, hi, move.line,
                                                          program.file, text)
            length = ss[-1]
            vc = conservative_limits(ss, vl, lim)
            ends.append((g0, g1))
            path.move_cap.append(BIG)
            samples.append((ss, vc, ats, jts))
        path.move_length.append(length)
        s += length
    path.total = s
    # nodes
    n_moves = len(program.moves)
    for index in range(n_moves):
        ss, vc, ats, jts = samples[index]
        base = path.move_s[index]
        count = len(ss)
        for j in range(count):
            if j == 0:
                if index == 0:
                    path.node_s.append(base)
                    path.node_vh.append(0.0)
                    path.node_left.append(-1)
                    path.node_right.append(index)
                    path.station.append(1)
                else:
                    prev = program.moves[index - 1]
                    stop = prev.exact_stop or prev.kind == MOVE_DWELL or program.moves[index].kind == MOVE_DWELL
                    if stop:
                        v = 0.0  # exact stop (G61, G9, before and after a dwell): at rest, a station
                    else:
                        ga = ends[index - 1][1]
                        gb = ends[index][0]
                        v = junction_limit(lim, ga.t, ga.k, gb.t, gb.k)
                        prev_cap = samples[index - 1][1][-1]
                        v = min(v, prev_cap, vc[0])
                    path.node_s.append(base)
                    path.node_vh.append(v)
                    path.node_left.append(index - 1)
                    path.node_right.append(index)
                    path.station.append(1 if stop else 0)
            elif j == count - 1:
                if index == n_moves - 1:
                    path.node_s.append(base + ss[j])
                    path.node_vh.append(0.0)
                    path.node_left.append(index)
                    path.node_right.append(-1)
                    path.station.append(1)
                # else: the next move's first node is this junction
            else:
                path.node_s.append(base + ss[j])
                path.node_vh.append(vc[j])
                path.node_left.append(index)
                path.node_right.append(index)
                path.station.append(0)
            if j < count - 1:
                path.int_move.append(index)
                path.int_at.append(min(ats[j], ats[j + 1]))
                path.int_jt.append(min(jts[j], jts[j + 1]))
                if program.moves[index].kind == MOVE_NURBS:
                    path.int_cap.append(max(vc[j], vc[j + 1]))
                else:
                    path.int_cap.append(path.move_cap[index])
    if n_moves and path.node_s[-1] != path.total:
        path.node_s[-1] = path.total
    return path
