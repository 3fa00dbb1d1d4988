"""NURBS parameter update: u(i+1) for a scheduled step length by first- or second-order Taylor expansion or
the RBF-network predictor (method 4, the predictor refined by Newton iterations on the arc length of the step, is
``Interpolator.nurbs_advance`` in engine.py). Mirrors ``fmus/interpolator/param_update.c`` (and
``param_update.h``)."""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Mapping, Sequence

from milling_twin.models.interpolator.nurbs import dot as _dot

METHOD_TAYLOR1, METHOD_TAYLOR2, METHOD_RBF, METHOD_CORRECTOR = 1, 2, 3, 4
METHOD_NAMES = {1: "taylor1", 2: "taylor2", 3: "rbf", 4: "corrector"}
RBF_HIDDEN, RBF_INPUTS = 5, 4
LANDING_SHARE = 0.1  # open loop: the share of a NURBS block over which the steps land on its end
MAX_NEWTON = 8   # method 4: Newton iterations on the arc length at most

@dataclass
class Rbf:
    width: float
    offset: tuple[float, float, float, float]
    scale: tuple[float, float, float, float]
    centers: tuple[tuple[float, float, float, float], ...]
    weights: tuple[float, ...]
    bias: float


def rbf_of(p: Mapping[str, float]) -> Rbf:
    return Rbf(p["rbf_width"], tuple(p[f"rbf_offset_{d}"] for d in range(1, 5)),
               tuple(p[f"rbf_scale_{d}"] for d in range(1, 5)),
               tuple(tuple(p[f"rbf_center_{j}_{d}"] for d in range(1, 5)) for j in range(1, 6)),
               tuple(p[f"rbf_weight_{j}"] for j in range(1, 6)), p["rbf_bias"])


def rbf_features(u2: float, u1: float, u0: float, length: float, ua: float, ub: float) -> tuple[float, ...]:
    """The network's raw inputs from u(i-2), u(i-1), u(i) and the step: the two parameter steps behind,
    the position in the block and the step length."""
    return (u0 - u2, u0 - u1, (u0 - ua) / (ub - ua), length)


def rbf_output(net: Rbf, raw: Sequence[float]) -> float:
    x = [(raw[d] - net.offset[d]) * net.scale[d] for d in range(4)]
    inv = 0.5 / (net.width * net.width)
    y = net.bias
    for c, w in zip(net.centers, net.weights):
        e0, e1, e2, e3 = x[0] - c[0], x[1] - c[1], x[2] - c[2], x[3] - c[3]
        y += w * math.exp(-(e0 * e0 + e1 * e1 + e2 * e2 + e3 * e3) * inv)
    return y


@dataclass
class NurbsState:
    """Per NURBS move: parameter history, the point and derivatives at u, the previous step's u''."""

    move: int = -1
    u: float = 0.0
    u1: float = 0.0
    u2: float = 0.0
    count: int = 0
    s_done: float = 0.0
    s_actual: float = 0.0
    point: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    d1: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    d2: list[float] = field(default_factory=lambda: [0.0, 0.0, 0.0])
    upp_prev: float = 0.0
    chord_prev: float = 0.0


def taylor_step(st: NurbsState, length: float, order: int) -> tuple[float, float, float]:
    """(du, u', u'') of the Taylor expansion of u(s) at the current point."""
    d1, d2 = st.d1, st.d2
    gg = _dot(d1, d1)
    g = math.sqrt(gg)
    up = 1.0 / g
    upp = -_dot(d1, d2) / (gg * gg)
    if order == 1:
        return length * up, up, upp
    return length * up + 0.5 * upp * length * length, up, upp


def curvature_squared(d1: Sequence[float], d2: Sequence[float]) -> float:
    """kappa^2 = |C' x C''|^2 / |C'|^6 from the u-derivatives C' = d1, C'' = d2 (0 where rounding makes it
    negative)."""
    gg = _dot(d1, d1)
    x = _dot(d1, d2)
    k2 = (_dot(d2, d2) * gg - x * x) / (gg * gg * gg)
    return k2 if k2 > 0.0 else 0.0


def arc_of_chord(chord: float, k2a: float, k2b: float) -> float:
    """The arc length over a chord between two points with curvature squared k2a and k2b: chord + k2m chord^3 /
    24 with k2m their mean (which cancels the chord^4 term)."""
    return chord + 0.5 * (k2a + k2b) * chord * chord * chord / 24.0


def predict(st: NurbsState, length: float, predictor: int, net: Rbf, ua: float, ub: float) -> float:
    if predictor == METHOD_TAYLOR1:
        return taylor_step(st, length, 1)[0]
    du, up, upp = taylor_step(st, length, 2)
    if predictor == METHOD_TAYLOR2 or st.count < 3:
        return du
    # history-augmented Taylor: u''' from the change of u'' over the previous chord, then the network
    uppp = (upp - st.upp_prev) / st.chord_prev if st.chord_prev > 0.0 else 0.0
    base = du + uppp * length * length * length / 6.0
    y = rbf_output(net, rbf_features(st.u2, st.u1, st.u, length, ua, ub))
    return base * (1.0 + y)
