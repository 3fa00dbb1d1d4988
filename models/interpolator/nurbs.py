"""NURBS evaluation: knot span search, B-spline basis derivatives (Piegl & Tiller A2.3), rational point and
derivatives, arc-length derivatives, Gauss-Legendre arc length. Mirrors ``fmus/interpolator/nurbs.c`` (and
``nurbs.h``) operation for operation."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Sequence

if TYPE_CHECKING:
    from milling_twin.models.interpolator.parser import NurbsCurve

def find_span(knots: Sequence[float], n: int, p: int, u: float, lo: int, hi: int) -> int:
    """Knot span index i with knots[i] <= u < knots[i+1], restricted to [lo, hi] (u at or past the
    end of the range gives hi, before it lo)."""
    if u >= knots[hi + 1]:
        return hi
    if u <= knots[lo]:
        return lo
    low, high = lo, hi + 1
    mid = (low + high) // 2
    while u < knots[mid] or u >= knots[mid + 1]:
        if u < knots[mid]:
            high = mid
        else:
            low = mid
        mid = (low + high) // 2
    return mid


def basis_derivatives(knots: Sequence[float], i: int, u: float, p: int, nd: int) -> list[list[float]]:
    """B-spline basis functions of span i and their derivatives up to nd (Piegl & Tiller, A2.3)."""
    ndu = [[0.0] * (p + 1) for _ in range(p + 1)]
    left = [0.0] * (p + 1)
    right = [0.0] * (p + 1)
    ndu[0][0] = 1.0
    for j in range(1, p + 1):
        left[j] = u - knots[i + 1 - j]
        right[j] = knots[i + j] - u
        saved = 0.0
        for r in range(j):
            ndu[j][r] = right[r + 1] + left[j - r]
            temp = ndu[r][j - 1] / ndu[j][r]
            ndu[r][j] = saved + right[r + 1] * temp
            saved = left[j - r] * temp
        ndu[j][j] = saved
    ders = [[0.0] * (p + 1) for _ in range(nd + 1)]
    for j in range(p + 1):
        ders[0][j] = ndu[j][p]
    a = [[0.0] * (p + 1), [0.0] * (p + 1)]
    for r in range(p + 1):
        s1, s2 = 0, 1
        a[0][0] = 1.0
        for k in range(1, nd + 1):
            d = 0.0
            rk, pk = r - k, p - k
            if r >= k:
                a[s2][0] = a[s1][0] / ndu[pk + 1][rk]
                d = a[s2][0] * ndu[rk][pk]
            j1 = 1 if rk >= -1 else -rk
            j2 = k - 1 if r - 1 <= pk else p - r
            for j in range(j1, j2 + 1):
                a[s2][j] = (a[s1][j] - a[s1][j - 1]) / ndu[pk + 1][rk + j]
                d += a[s2][j] * ndu[rk + j][pk]
            if r <= pk:
                a[s2][k] = -a[s1][k - 1] / ndu[pk + 1][r]
                d += a[s2][k] * ndu[r][pk]
            ders[k][r] = d
            s1, s2 = s2, s1
    factor = float(p)
    for k in range(1, nd + 1):
        for j in range(p + 1):
            ders[k][j] *= factor
        factor *= float(p - k)
    return ders


_BINOMIAL = ((1.0,), (1.0, 1.0), (1.0, 2.0, 1.0), (1.0, 3.0, 3.0, 1.0))


class Nurbs:
    """A rational B-spline with homogeneous control points (w x, w y, w z, w)."""

    def __init__(self, curve: NurbsCurve):
        self.p = curve.degree
        self.n = len(curve.points) - 1
        self.knots = list(curve.knots)
        self.pw = [(w * x, w * y, w * z, w) for (x, y, z), w in zip(curve.points, curve.weights)]

    def evaluate(self, u: float, nd: int, lo: int, hi: int) -> list[list[float]]:
        """Point and derivatives d^k C / du^k, k = 0..nd (nd <= 3), span searched in [lo, hi]."""
        p = self.p
        i = find_span(self.knots, self.n, p, u, lo, hi)
        ders = basis_derivatives(self.knots, i, u, p, nd)
        aw = []
        for k in range(nd + 1):
            x = y = z = w = 0.0
            row = ders[k]
            for j in range(p + 1):
                c = self.pw[i - p + j]
                b = row[j]
                x += b * c[0]
                y += b * c[1]
                z += b * c[2]
                w += b * c[3]
            aw.append((x, y, z, w))
        out: list[list[float]] = []
        w0 = aw[0][3]
        for k in range(nd + 1):
            vx, vy, vz = aw[k][0], aw[k][1], aw[k][2]
            for m in range(1, k + 1):
                f = _BINOMIAL[k][m] * aw[m][3]
                prev = out[k - m]
                vx -= f * prev[0]
                vy -= f * prev[1]
                vz -= f * prev[2]
            out.append([vx / w0, vy / w0, vz / w0])
        return out

    def span_range(self, u0: float, u1: float) -> tuple[int, int]:
        """First and last span index with positive length inside [u0, u1]."""
        p, kn = self.p, self.knots
        lo = p
        while kn[lo + 1] <= u0:
            lo += 1
        hi = self.n
        while kn[hi] >= u1:
            hi -= 1
        return lo, hi


def dot(a, b) -> float:
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def arc_length_derivatives(d: list[list[float]]) -> tuple[float, list[float], list[float], list[float], float, float]:
    """From C, C', C'', C''' (u-derivatives): speed g = |C'|, unit tangent T, d2C/ds2, d3C/ds3 and
    du/ds, d2u/ds2."""
    d1, d2, d3 = d[1], d[2], d[3]
    gg = dot(d1, d1)
    g = math.sqrt(gg)
    up = 1.0 / g
    d12 = dot(d1, d2)
    upp = -d12 / (gg * gg)
    uppp = -(dot(d2, d2) + dot(d1, d3)) / (gg * gg * g) + 4.0 * d12 * d12 / (gg * gg * gg * g)
    t = [d1[0] * up, d1[1] * up, d1[2] * up]
    up2 = up * up
    k = [d2[a] * up2 + d1[a] * upp for a in range(3)]
    up3 = up2 * up
    kp = [d3[a] * up3 + 3.0 * d2[a] * up * upp + d1[a] * uppp for a in range(3)]
    return g, t, k, kp, up, upp


# Gauss-Legendre, 5 points on [-1, 1]
GL_NODES = (-0.9061798459386640, -0.5384693101056831, 0.0, 0.5384693101056831, 0.9061798459386640)
GL_WEIGHTS = (0.2369268850561891, 0.4786286704993665, 0.5688888888888889, 0.4786286704993665,
              0.2369268850561891)


def gauss_length(curve: Nurbs, ua: float, ub: float, lo: int, hi: int) -> float:
    half = 0.5 * (ub - ua)
    mid = 0.5 * (ua + ub)
    total = 0.0
    for node, weight in zip(GL_NODES, GL_WEIGHTS):
        d = curve.evaluate(mid + half * node, 1, lo, hi)[1]
        total += weight * math.sqrt(dot(d, d))
    return total * half


def arc_length(curve: Nurbs, ua: float, ub: float, lo: int, hi: int) -> float:
    """Arc length from ua to ub (ua <= ub): Gauss-Legendre on each knot span's part (exact to rounding for short
    steps, no quadrature across a knot). Mirrors nurbs_arc_length."""
    kn = curve.knots
    a = ua
    total = 0.0
    span = find_span(kn, curve.n, curve.p, ua, lo, hi)
    while a < ub and span <= hi:
        b = kn[span + 1] if kn[span + 1] < ub else ub
        if b > a:
            total += gauss_length(curve, a, b, lo, hi)
            a = b
        span += 1
    if a < ub:
        total += gauss_length(curve, a, ub, lo, hi)
    return total
