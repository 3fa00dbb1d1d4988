"""An independent checker of the Interpolator: what the engine's sampled trajectory does against the limits it is
given, measured from the positions alone (and the exact geometry where the test knows it).

Independence: nothing here imports the engine's modules (``models/interpolator`` nurbs, path, schedule, parser).
The only project import is the model definition ``INTERPOLATOR`` (the parameters' defaults: the limits the engine
is documented to hold). NURBS are evaluated by this module's own de Boor algorithm on homogeneous control points,
their derivatives by differentiated control polygons, the time bound by this module's own forward/backward pass.

Input: a trajectory of the C engine (``build/tools/interp_run --csv``, one row per interpolation period: tick,
t, x, y, z, feed, path_acceleration, u, line, move, ...; ``run_engine``) or any table with those columns (the FMU
or the Python reference), the start position (``start_x..z``, the tool at rest before tick 1) and optionally the
exact geometry (``Nurbs`` pieces) and the programmed feed per line.

Measured quantities (T the period; P_i the positions with three copies of the start position before tick 1 and
three of the last position after the end: the tool is at rest before and after the program):

- axis velocity, acceleration, jerk: first, second and third backward differences of P per axis, / T, T^2, T^3.
  The k-th difference / T^k of samples of a smooth motion is the k-th derivative averaged with a positive kernel
  of unit mass (the B-spline of degree k-1 over k periods), so it never exceeds the continuous maximum: a
  measured excess is a real excess of the sampled motion (what the drives receive), never a differencing
  artefact. Rounding noise: positions are doubles of magnitude <= 1 m (ulp <= 2.2e-16 m); the third difference
  adds at most 8 ulp -> 1.8e-6 m/s^3 at T = 1 ms, 1e-8 of the default axis jerk (300 m/s^3). The engine's own
  step noise (the NURBS parameter update: relative chord-length tolerance 1e-6 by default, measured fluctuation
  ~1e-6) is e ~ 1e-6 * v * T ~ 1e-10 m at 0.1 m/s, giving at most 8 e / T^3 ~ 0.8 m/s^3 in the worst alignment
  (0.27 % of 300), typically 100 times less (the corrector's fluctuation is ~1e-8, 0.003 %): the 0.1 % tolerance
  is above the noise floor of a converged corrector, not above that of the open-loop Taylor methods, which is
  why the limits are checked with the default method 4.
- centripetal acceleration |A_i - (A_i . t_i) t_i| (A_i the central second difference / T^2, t_i the unit
  vector along P_i+1 - P_i-1; = v^2 kappa: on a circle at constant speed the central difference is exactly normal,
  of magnitude chord_speed^2 / radius <= v^2 kappa); where P_i+1 = P_i-1 (at rest) all of A_i is tangential.
- tangential acceleration and jerk: second and third differences of the path length s / T^2, T^3. With the exact
  geometry s is the curve's own arc length at the samples' projections (Gauss-Legendre on this module's
  derivative); without it, the cumulative chord (what the engine steps by on NURBS; on arcs it steps by arc
  length, and the chord's deficit (kappa h)^2 / 24 of a step changes so slowly that its third difference stays
  below T^2 (kappa^2 v^3)'' / 24, under 0.05 % of J on the corpus' arcs). Both are defined at a reversal of the
  path, where a projection on t_i is not. Noise: the engine's chords deviate from its scheduled steps by up to
  corrector_tolerance x step (1e-6 x 1e-4 m at 0.1 m/s and 1 ms): up to 8e-10 m / T^3 = 0.8 m/s^3 in s'''
  (0.8 % of the default 100 m/s^3) in the worst alignment. That is jitter of the commanded positions, which the
  drives receive, so it is counted (the engine's own ``s`` column holds J to 1e-9).
- at a junction of two blocks with a turn (more than 1e-3 rad) the engine stops between two ticks; the chord of
  that period cuts the corner, so the tangential quantities and the step error leave out the periods next to
  it (``corner_periods``); the axis limits, which need no direction, cover them.
- step error: the chord |P_i - P_i-1| against the step the schedule outputs promise, the Hermite rule
  T/2 (v_i-1 + v_i) + T^2/12 (a_i-1 - a_i) with v = ``feed``, a = ``path_acceleration``: exact for the jerk-limited
  S-curve (v piecewise quadratic) except over a switch of jerk, where its error is at most
  max_x x (2x - T)(x - T) / 12 * dJ = 0.008 dJ T^3 <= 0.016 J T^3; so a step is wrong when it is off by more
  than 0.1 % of the step + 0.02 J T^3 + the chord/arc difference (kappa h)^2 / 24 of the step (arcs are stepped
  by arc length, NURBS by chord). Standstill: a period whose chord is below 1e-3 of a promised step above that
  floor (the tool stands while ``feed`` says it moves); early arrival: the promised steps of the standstill
  periods right before a block ends (the tool arrived that much ahead of its schedule); a jump: a chord above
  the promised step by more than the tolerance (e.g. onto the end point).
- feed fluctuation: |chord - promised step| / promised step over the periods at >= 10 % of the programmed feed
  away from block ends (max and mean).
- with the exact geometry: distance of every sample from the curve (Newton projection from an arc-length guess),
  chord error (the largest distance of the curve between two samples' parameters from their chord, at 7
  interior points),
  end-point error (last sample vs the curve's end), the engine's ``u`` against the parameter found here (raw and
  normalised to 0..1), and the acceleration-limited time bound: a velocity limit curve on a grid dense in u and
  in arc length: min(F, chord limit (2/T) sqrt(2 rho delta - delta^2), centripetal sqrt(A_c rho),
  curvature jerk (J rho^2)^(1/3)), zero at both ends and at C0 knots (multiplicity = degree), then the time-optimal
  forward/backward pass under the tangential acceleration limit A (v^2 recurrences solved with cumulative minima);
  time = sum 2 ds / (v_k + v_k+1). Every feasible schedule under the same limits needs at least that long (jerk
  ignored), so ratio = engine time / bound >= 1.
- without the geometry (programs with lines, arcs, cycles): the same bound on the sampled path (s = cumulative
  chord, kappa = Menger curvature of three neighbouring samples, F per line scanned from the program, a stop
  where the direction turns by more than 1e-3 rad between two blocks), compared with the engine's moving time
  (periods at zero ``feed`` without motion, i.e. dwells, excluded). An estimate, not a strict bound.

A limit is violated when the measured maximum exceeds it by more than ``TOLERANCE`` (0.1 %).
"""
from __future__ import annotations

import math
import os
import re
import subprocess
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
ENGINE = Path(os.environ.get("MILLING_TWIN_INTERP_RUN", REPO / "build" / "tools" / "interp_run"))
TOLERANCE = 1e-3
REST_PADDING = 3
# Fanuc's G6.2 P is the ORDER (degree + 1); the parser reads it so since fbbe600 (before: the degree).
NURBS_P_IS_ORDER = True
LIMIT_NAMES = ("period", "max_feed", "rapid_feed", "acceleration", "jerk", "centripetal_acceleration",
               "chord_error", "axis_acceleration_x", "axis_acceleration_y", "axis_acceleration_z",
               "axis_jerk_x", "axis_jerk_y", "axis_jerk_z", "start_x", "start_y", "start_z")


def default_limits(**overrides: float) -> dict[str, float]:
    """The engine's documented limits: the model definition's parameter defaults, updated by ``overrides``."""
    from milling_twin.models.interpolator.definition import INTERPOLATOR
    start = {v.name: float(v.start) for v in INTERPOLATOR.of("parameter") if v.name in LIMIT_NAMES}
    unknown = set(overrides) - set(start)
    if unknown:
        raise KeyError(f"not a limit parameter: {sorted(unknown)}")
    start.update({k: float(v) for k, v in overrides.items()})
    return start


class EngineTimeout(RuntimeError):
    """The engine did not finish within the wall-clock time it was given."""


class EngineError(RuntimeError):
    """The engine refused the program (its message in ``message``)."""

    def __init__(self, message: str):
        self.message = message
        super().__init__(message)


@dataclass
class Trajectory:
    t: np.ndarray
    p: np.ndarray          # (N, 3) machine positions, m
    feed: np.ndarray
    acc: np.ndarray
    u: np.ndarray
    line: np.ndarray
    move: np.ndarray
    start: np.ndarray      # position before tick 1


def load_csv(path: Path, start=(0.0, 0.0, 0.0)) -> Trajectory:
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    if data.shape[0] == 0:
        raise EngineError(f"{path}: no rows")
    return Trajectory(t=data[:, 1], p=data[:, 2:5].copy(), feed=data[:, 5], acc=data[:, 6], u=data[:, 7],
                      line=data[:, 8].astype(int), move=data[:, 9].astype(int), start=np.asarray(start, float))


def run_engine(program: Path, params: dict[str, float] | None = None, workdir: Path | None = None,
               timeout: float = 600.0, options: tuple[str, ...] = ()) -> Trajectory:
    """Runs ``interp_run`` on ``program`` with ``params`` (FMU names, SI) and further command-line ``options``
    (``--dialect``, ``--tool-table``) and returns its trajectory; ``EngineTimeout`` after ``timeout`` s."""
    params = dict(params or {})
    with tempfile.TemporaryDirectory(dir=workdir) as tmp:
        csv = Path(tmp) / "out.csv"
        cmd = [str(ENGINE), "--csv", str(csv)]
        for name, value in params.items():
            cmd += ["--param", f"{name}={value!r}"]
        cmd += list(options) + [str(program)]
        try:
            done = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired as exc:
            raise EngineTimeout(f"{program}: not finished after {timeout:.1f} s of wall time") from exc
        if done.returncode != 0:
            message = (done.stderr or done.stdout).strip()
            if done.returncode < 0:
                message = f"{program}: the engine crashed (signal {-done.returncode}) {message}".strip()
            raise EngineError(message)
        start = [params.get(f"start_{a}", 0.0) for a in "xyz"]
        return load_csv(csv, start)


def run_reference(text: str, params: dict[str, float] | None = None, max_ticks: int = 2_000_000) -> Trajectory:
    """The same trajectory from the Python reference engine (``milling_twin.models.interpolator.engine``, the
    mirror of the C engine), ticked until it finishes: the check's input only, nothing of it is used to check."""
    from milling_twin.models.interpolator.engine import Interpolator
    params = dict(params or {})
    engine = Interpolator(text, params)
    engine.set_override(1.0, 0.0)  # planned at initialization, as the C driver does
    rows = []
    while not engine.finished and len(rows) < max_ticks:
        engine.tick()
        o = engine.out
        rows.append((engine.tick_count * engine.period, o["x"], o["y"], o["z"], o["feed"], o["path_acceleration"],
                     o["u"], o["line_number"], engine.move))
    data = np.array(rows, float)
    return Trajectory(t=data[:, 0], p=data[:, 1:4].copy(), feed=data[:, 4], acc=data[:, 5], u=data[:, 6],
                      line=data[:, 7].astype(int), move=data[:, 8].astype(int),
                      start=np.array([params.get(f"start_{a}", 0.0) for a in "xyz"]))


# ---------------------------------------------------------------------------------------------------- geometry

def _deboor(ctrl: np.ndarray, knots: np.ndarray, degree: int, u: np.ndarray) -> np.ndarray:
    """Points of the (non-rational) B-spline with control points ``ctrl`` (n, d) at parameters ``u`` (m,)."""
    n = len(ctrl)
    if degree == 0:
        span = np.clip(np.searchsorted(knots, u, side="right") - 1, 0, n - 1)
        return ctrl[span]
    span = np.clip(np.searchsorted(knots, u, side="right") - 1, degree, n - 1)
    d = np.stack([ctrl[span - degree + j] for j in range(degree + 1)], axis=0)  # (p+1, m, dim)
    for r in range(1, degree + 1):
        for j in range(degree, r - 1, -1):
            left = knots[span - degree + j]
            right = knots[span + 1 + j - r]
            den = right - left
            alpha = np.where(den > 0, (u - left) / np.where(den > 0, den, 1.0), 0.0)[:, None]
            d[j] = (1.0 - alpha) * d[j - 1] + alpha * d[j]
    return d[degree]


def _derivative_polygon(ctrl: np.ndarray, knots: np.ndarray, degree: int) -> tuple[np.ndarray, np.ndarray]:
    """Control points and knots of the derivative (degree - 1) of a B-spline."""
    den = knots[degree + 1:degree + len(ctrl)] - knots[1:len(ctrl)]
    factor = np.where(den > 0, degree / np.where(den > 0, den, 1.0), 0.0)[:, None]
    return factor * (ctrl[1:] - ctrl[:-1]), knots[1:-1]


@dataclass
class Nurbs:
    degree: int
    points: np.ndarray     # (n, 3), m
    weights: np.ndarray
    knots: np.ndarray
    feed: float            # m/s (programmed)
    _polys: list = field(default_factory=list, repr=False)

    def __post_init__(self):
        self.points = np.asarray(self.points, float)
        self.weights = np.asarray(self.weights, float)
        self.knots = np.asarray(self.knots, float)
        hom = np.column_stack([self.points * self.weights[:, None], self.weights])
        polys = [(hom, self.knots, self.degree)]
        for _ in range(2):
            c, k, p = polys[-1]
            if p == 0:
                polys.append((None, k, 0))      # the derivative of a piecewise constant: zero
            else:
                c2, k2 = _derivative_polygon(c, k, p)
                polys.append((c2, k2, p - 1))
        self._polys = polys

    @property
    def bounds(self) -> tuple[float, float]:
        return float(self.knots[self.degree]), float(self.knots[-self.degree - 1])

    def derivatives(self, u: np.ndarray):
        """C, C', C'' at ``u`` (quotient rule on the homogeneous curve)."""
        u = np.asarray(u, float)
        a0, a1, a2 = (_deboor(c, k, p, u) if c is not None else np.zeros((len(u), 4))
                      for c, k, p in self._polys)
        w0, w1, w2 = a0[:, 3:], a1[:, 3:], a2[:, 3:]
        c0 = a0[:, :3] / w0
        c1 = (a1[:, :3] - w1 * c0) / w0
        c2 = (a2[:, :3] - 2 * w1 * c1 - w2 * c0) / w0
        return c0, c1, c2

    def point(self, u) -> np.ndarray:
        hom = _deboor(self._polys[0][0], self.knots, self.degree, np.atleast_1d(np.asarray(u, float)))
        return hom[:, :3] / hom[:, 3:]

    def curvature(self, u) -> np.ndarray:
        _, c1, c2 = self.derivatives(u)
        speed = np.linalg.norm(c1, axis=1)
        cube = speed ** 3
        cross = np.linalg.norm(np.cross(c1, c2), axis=1)
        return np.where(cube > 0, cross / np.where(cube > 0, cube, 1.0), np.inf)

    def corners(self) -> list[float]:
        """Inner knots of multiplicity >= degree (tangent may break: the path must stop there)."""
        a, b = self.bounds
        values, counts = np.unique(self.knots, return_counts=True)
        return [float(v) for v, c in zip(values, counts) if a < v < b and c >= self.degree]

    def grid(self, n: int = 4000) -> tuple[np.ndarray, np.ndarray]:
        """Parameters dense in u and in arc length (n each, plus the knots) and the arc length at them."""
        a, b = self.bounds
        u = np.unique(np.concatenate([np.linspace(a, b, n), self.knots[(self.knots >= a) & (self.knots <= b)]]))
        s = self._arc_length(u)
        target = np.linspace(0.0, s[-1], n)
        u2 = np.interp(target, s, u)
        u = np.unique(np.concatenate([u, u2]))
        return u, self._arc_length(u)

    def _arc_length(self, u: np.ndarray) -> np.ndarray:
        """Cumulative arc length at the (increasing) parameters ``u``. The inner knots are added to the
        intervals: the speed along u may jump or bend at a knot, where one Gauss-Legendre rule across it would be
        wrong (a quadratic's knot between two samples read 1.093e-7 m for 9.02e-8)."""
        a, b = self.bounds
        inner = np.unique(self.knots[(self.knots > max(a, u[0])) & (self.knots < min(b, u[-1]))])
        if not len(inner):
            return self._arc_length_smooth(u)
        full = np.unique(np.concatenate([u, inner]))
        return self._arc_length_smooth(full)[np.searchsorted(full, u)]

    def _arc_length_smooth(self, u: np.ndarray) -> np.ndarray:
        # Gauss-Legendre, 5 nodes per interval (no knot inside an interval)
        x, w = np.polynomial.legendre.leggauss(5)
        lo, hi = u[:-1], u[1:]
        mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
        nodes = (mid[:, None] + half[:, None] * x[None, :]).ravel()
        _, c1, _ = self.derivatives(nodes)
        speed = np.linalg.norm(c1, axis=1).reshape(len(lo), len(x))
        return np.concatenate([[0.0], np.cumsum(half * (speed @ w))])

    def project(self, points: np.ndarray, guess: np.ndarray, iterations: int = 12):
        """Nearest parameters (local Newton from ``guess``) and the distances of ``points`` from the curve."""
        a, b = self.bounds
        u = np.clip(np.asarray(guess, float).copy(), a, b)
        best_u = u.copy()
        best_d = np.linalg.norm(self.point(u) - points, axis=1)
        for _ in range(iterations):
            c0, c1, c2 = self.derivatives(u)
            r = c0 - points
            g = np.sum(c1 * r, axis=1)
            h = np.sum(c2 * r, axis=1) + np.sum(c1 * c1, axis=1)
            step = np.where(h > 0, -g / np.where(h > 0, h, 1.0), 0.0)
            u = np.clip(u + step, a, b)
            d = np.linalg.norm(self.point(u) - points, axis=1)
            better = d < best_d
            best_u = np.where(better, u, best_u)
            best_d = np.where(better, d, best_d)
        return best_u, best_d

    def gcode(self, feed_mm_min: float, p_is_order: bool | None = None) -> list[str]:
        """The G6.2 block (mm) of this curve, with P the order or the degree (``NURBS_P_IS_ORDER``)."""
        order = NURBS_P_IS_ORDER if p_is_order is None else p_is_order
        lines = []
        for i, (pt, w) in enumerate(zip(self.points * 1e3, self.weights)):
            head = f"G6.2 P{self.degree + 1 if order else self.degree} " if i == 0 else ""
            tail = f" F{_num(feed_mm_min)}" if i == 0 else ""
            lines.append(f"{head}K{_num(self.knots[i])} X{_num(pt[0])} Y{_num(pt[1])} Z{_num(pt[2])} "
                         f"R{_num(w)}{tail}")
        lines += [f"K{_num(k)}" for k in self.knots[len(self.points):]]
        return lines


def _num(x: float) -> str:
    text = f"{float(x):.12g}"
    return "0" if text in ("-0", "0") else text


def curve_from_rounded(degree: int, points_mm, weights, knots, feed_mm_min: float) -> Nurbs:
    """A curve whose values are exactly those its G-code prints (12 significant digits), in metres."""
    pts = np.array([[float(_num(c)) for c in p] for p in points_mm]) * 1e-3
    return Nurbs(degree, pts, np.array([float(_num(w)) for w in weights]),
                 np.array([float(_num(k)) for k in knots]), float(_num(feed_mm_min)) / 60e3)


# ---------------------------------------------------------------------------------------------------- time bound

def _pass_time(s: np.ndarray, vlc: np.ndarray, acc: float) -> float:
    """Time-optimal forward/backward pass on the velocity limit ``vlc`` (0 where the path must stop)."""
    c = vlc ** 2
    w = 2 * acc * s + np.minimum.accumulate(c - 2 * acc * s)               # forward: w_k <= w_j + 2A(s_k - s_j)
    r = s[-1] - s
    w2 = 2 * acc * r + np.minimum.accumulate((c - 2 * acc * r)[::-1])[::-1]   # backward, from the end
    v = np.sqrt(np.maximum(np.minimum(w, w2), 0.0))
    ds = np.diff(s)
    vs = v[1:] + v[:-1]
    moving = ds > 0
    rest = moving & (vs <= 0)            # a stop at both ends: rest to rest at A, 2 sqrt(ds / A)
    cruise = moving & ~rest
    return float(np.sum(2 * ds[cruise] / vs[cruise]) + np.sum(2 * np.sqrt(ds[rest] / acc)))


def _vlc(kappa: np.ndarray, feed: np.ndarray, lim: dict[str, float], chord: float) -> np.ndarray:
    T = lim["period"]
    rho = 1.0 / np.maximum(kappa, 1e-100)
    chord_v = np.where(rho > chord, 2.0 / T * np.sqrt(np.maximum(2 * rho * chord - chord ** 2, 0.0)), 4 * rho / T)
    return np.minimum.reduce([feed, chord_v, np.sqrt(lim["centripetal_acceleration"] * rho),
                              np.cbrt(lim["jerk"] * rho ** 2)])


def nurbs_time_bound(curve: Nurbs, lim: dict[str, float], n: int = 4000) -> float:
    u, s = curve.grid(n)
    feed = np.full(len(u), min(curve.feed, lim["max_feed"]))
    vlc = _vlc(curve.curvature(u), feed, lim, lim["chord_error"])
    vlc[0] = vlc[-1] = 0.0
    for c in curve.corners():
        vlc[np.argmin(np.abs(u - c))] = 0.0
    return _pass_time(s, vlc, lim["acceleration"])


# ---------------------------------------------------------------------------------------------------- measuring

@dataclass
class Report:
    figures: dict = field(default_factory=dict)
    violations: list = field(default_factory=list)      # (quantity, measured, limit, excess ratio)

    def limit(self, name: str, measured: float, bound: float):
        self.figures[name] = measured
        self.figures[name + "_limit"] = bound
        if measured > bound * (1 + TOLERANCE):
            self.violations.append((name, measured, bound, measured / bound - 1.0))

    def excess(self) -> dict[str, float]:
        return {name: ratio for name, _, _, ratio in self.violations}


def _padded(traj: Trajectory) -> np.ndarray:
    head = np.repeat(traj.start[None, :], REST_PADDING, axis=0)
    tail = np.repeat(traj.p[-1:], REST_PADDING, axis=0)
    return np.concatenate([head, traj.p, tail])


def check(traj: Trajectory, lim: dict[str, float], *, curve: Nurbs | None = None,
          line_feed: dict[int, float] | None = None) -> Report:
    """Measures ``traj`` against the limits ``lim`` (``default_limits``); ``curve`` the exact geometry of a
    single-NURBS program, ``line_feed`` the highest path speed each program line may command (m/s)."""
    rep = Report()
    T = lim["period"]
    P = _padded(traj)
    k = REST_PADDING
    d1 = np.diff(P, axis=0)
    d2 = np.diff(P, n=2, axis=0)
    d3 = np.diff(P, n=3, axis=0)
    for i, axis in enumerate("xyz"):
        rep.limit(f"axis_acceleration_{axis}", float(np.max(np.abs(d2[:, i]))) / T ** 2,
                  lim[f"axis_acceleration_{axis}"])
        rep.limit(f"axis_jerk_{axis}", float(np.max(np.abs(d3[:, i]))) / T ** 3, lim[f"axis_jerk_{axis}"])
    speed = np.linalg.norm(d1, axis=1) / T
    top = max(lim["max_feed"], lim["rapid_feed"]) if line_feed is None else None
    if curve is not None:
        top = min(curve.feed, lim["max_feed"])
    if top is not None:
        rep.limit("path_speed", float(speed.max()), top)
    else:
        lines = np.concatenate([np.full(k, traj.line[0]), traj.line, np.full(k, traj.line[-1])])
        # a period that spans two blocks may move at either block's speed
        per_row = np.array([line_feed.get(int(n), lim["max_feed"]) for n in lines])
        allowed = np.maximum(per_row[1:], per_row[:-1])
        ratio = speed / np.maximum(allowed, 1e-300)
        worst = int(np.argmax(ratio))
        rep.limit("path_speed_over_line_feed", float(ratio[worst]), 1.0)
    # tangential / centripetal from central second differences at P_1 .. P_-2
    chord2 = P[2:] - P[:-2]
    n2 = np.linalg.norm(chord2, axis=1)
    tangent = np.where(n2[:, None] > 0, chord2 / np.where(n2 > 0, n2, 1.0)[:, None], 0.0)
    acc = d2 / T ** 2
    a_t = np.sum(acc * tangent, axis=1)
    a_t = np.where(n2 > 0, a_t, np.linalg.norm(acc, axis=1))
    normal = acc - a_t[:, None] * tangent
    a_n = np.where(n2 > 0, np.linalg.norm(normal, axis=1), 0.0)
    corner = _corner_rows(traj, P)
    # padded sample index of each row: k + row; the windows of second/third differences touching a corner row
    pad_corner = np.concatenate([np.zeros(k, bool), corner, np.zeros(k, bool)])
    if curve is None:
        # along the path: differences of the cumulative chord (defined at reversals too, where t_i is not)
        s_chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(d1, axis=1))])
        d2s, d3s = np.diff(s_chord, n=2), np.diff(s_chord, n=3)
        near2 = pad_corner[:-2] | pad_corner[1:-1] | pad_corner[2:]
        near3 = near2[:-1] | near2[1:]
        rep.limit("tangential_acceleration", float(np.max(np.abs(d2s[~near2]), initial=0.0)) / T ** 2,
                  lim["acceleration"])
        rep.limit("tangential_jerk", float(np.max(np.abs(d3s[~near3]), initial=0.0)) / T ** 3, lim["jerk"])
        rep.limit("centripetal_acceleration", float(np.max(a_n)), lim["centripetal_acceleration"])
    else:
        rep.figures["tangential_acceleration_samples"] = float(np.max(np.abs(a_t)))
        rep.figures["tangential_jerk_samples"] = float(np.max(np.abs(np.diff(a_t)))) / T
        rep.figures["centripetal_acceleration_samples"] = float(np.max(a_n))
    rep.figures["path_jerk"] = float(np.max(np.linalg.norm(d3, axis=1))) / T ** 3
    # steps against the schedule's promise
    v = np.concatenate([[0.0], traj.feed])
    a = np.concatenate([[0.0], traj.acc])
    promised = T / 2 * (v[:-1] + v[1:]) + T ** 2 / 12 * (a[:-1] - a[1:])
    chords = np.linalg.norm(d1[k - 1:k - 1 + len(traj.t)], axis=1)
    # Menger curvature at each sample (for the chord/arc allowance and the sampled bound)
    kappa = _menger(P)[k - 1:k - 1 + len(traj.t)]
    floor = max(0.02 * lim["jerk"] * T ** 3, 0.01 * lim["chord_error"])
    allowance = TOLERANCE * promised + floor + (kappa * promised) ** 2 / 24 * promised
    err = chords - promised
    bad = (np.abs(err) > allowance) & ~corner
    rep.figures["corner_periods"] = int(np.sum(corner))
    rep.figures["steps_off"] = int(np.sum(bad))
    rep.figures["worst_step_error"] = float(np.max(np.abs(err))) if len(err) else 0.0
    rep.figures["jumps"] = int(np.sum(err > allowance))
    stand = (chords < 1e-3 * promised) & (promised > floor) & ~corner
    rep.figures["standstill_with_feed"] = int(np.sum(stand))
    ends = np.concatenate([traj.move[1:] != traj.move[:-1], [True]])
    early = 0.0
    run = 0.0
    for i in range(len(stand)):
        run = run + promised[i] if stand[i] else 0.0
        if ends[i]:
            early = max(early, run)
            run = 0.0
    rep.figures["early_arrival"] = early
    if rep.figures["steps_off"]:
        rep.violations.append(("steps_off_schedule", rep.figures["steps_off"], 0, math.inf))
    # fluctuation away from block ends, at >= 10 % of the programmed feed
    near_end = np.zeros(len(ends), bool)
    for shift in range(-2, 3):
        near_end |= np.roll(ends, shift)
    fast = traj.feed >= 0.1 * (top if top is not None else max(traj.feed.max(), 1e-300))
    use = fast & ~near_end & (promised > 0)
    fl = np.abs(err[use]) / promised[use] if np.any(use) else np.zeros(1)
    rep.figures["fluctuation_max"] = float(fl.max())
    rep.figures["fluctuation_mean"] = float(fl.mean())
    rep.figures["end_at_rest"] = bool(chords[-1] <= floor or abs(traj.feed[-1]) == 0.0)
    rep.figures["time"] = float(traj.t[-1])
    if curve is not None:
        _check_geometry(rep, traj, lim, curve, corner)
    else:
        _sampled_bound(rep, traj, lim, P, line_feed)
    return rep


def _corner_rows(traj: Trajectory, P: np.ndarray) -> np.ndarray:
    """Rows whose period holds a junction of two blocks with a turn of more than 1e-3 rad (the chord of such a
    period cuts the corner, so its length is not the distance travelled)."""
    k = REST_PADDING
    rows = np.zeros(len(traj.t), bool)
    for i in np.nonzero(traj.move[1:] != traj.move[:-1])[0] + 1:
        a = P[k + i - 1] - P[k + i - 2]
        b = P[k + i + 1] - P[k + i]
        na, nb = np.linalg.norm(a), np.linalg.norm(b)
        if na == 0 or nb == 0 or np.dot(a, b) < math.cos(1e-3) * na * nb:
            rows[max(i - 1, 0):i + 2] = True
    return rows


def _menger(P: np.ndarray) -> np.ndarray:
    """Curvature of the circle through P_i-1, P_i, P_i+1 at every P_i (0 at the ends and where points coincide)."""
    a = P[1:-1] - P[:-2]
    b = P[2:] - P[1:-1]
    c = P[2:] - P[:-2]
    la, lb, lc = (np.linalg.norm(x, axis=1) for x in (a, b, c))
    cross = np.linalg.norm(np.cross(a, b), axis=1)
    den = la * lb * lc
    kappa = np.where(den > 1e-300, 2 * cross / np.where(den > 1e-300, den, 1.0), 0.0)
    return np.concatenate([[0.0], kappa, [0.0]])


def _check_geometry(rep: Report, traj: Trajectory, lim: dict[str, float], curve: Nurbs,
                    corner: np.ndarray) -> None:
    u_grid, s_grid = curve.grid()
    pts = np.concatenate([traj.start[None, :], traj.p])
    s_chord = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    guess = np.interp(np.minimum(s_chord, s_grid[-1]), s_grid, u_grid)
    u, dist = curve.project(pts, guess)
    # a second start where the curve turns sharply (the arc-length guess can fall on a neighbouring branch): the
    # engine's u read as normalised and as raw; only a guess, the distance is this module's own evaluation
    a, b = curve.bounds
    eu = np.concatenate([[0.0], traj.u])
    for other in (a + eu * (b - a), eu):
        u2, d2 = curve.project(pts, other)
        better = d2 < dist
        u, dist = np.where(better, u2, u), np.where(better, d2, dist)
    rep.figures["max_distance_from_curve"] = float(dist.max())
    # the path's own arc length at the samples (rest padding before and after), its differences and v^2 kappa
    s_exact = curve._arc_length(np.maximum.accumulate(u))
    S = np.concatenate([np.full(REST_PADDING - 1, 0.0), s_exact, np.full(REST_PADDING, s_exact[-1])])
    T = lim["period"]
    rep.limit("tangential_acceleration", float(np.max(np.abs(np.diff(S, n=2)))) / T ** 2, lim["acceleration"])
    rep.limit("tangential_jerk", float(np.max(np.abs(np.diff(S, n=3)))) / T ** 3, lim["jerk"])
    v_c = (S[2:] - S[:-2]) / (2 * T)
    kappa = np.concatenate([np.zeros(REST_PADDING - 2), curve.curvature(u), np.zeros(REST_PADDING - 1)])
    rep.limit("centripetal_acceleration", float(np.max(v_c ** 2 * np.where(np.isfinite(kappa), kappa, 0.0))),
              lim["centripetal_acceleration"])
    # the curve between two samples' parameters against their chord: 7 interior points, distance to the segment
    lam = np.linspace(0.0, 1.0, 9)[1:-1]
    grid = (u[:-1, None] + (u[1:] - u[:-1])[:, None] * lam[None, :]).ravel()
    inner = curve.point(grid).reshape(len(u) - 1, len(lam), 3)
    seg = pts[1:] - pts[:-1]
    len2 = np.maximum(np.sum(seg * seg, axis=1), 1e-300)
    rel = inner - pts[:-1, None, :]
    t = np.clip(np.sum(rel * seg[:, None, :], axis=2) / len2[:, None], 0.0, 1.0)
    gap = np.linalg.norm(rel - t[:, :, None] * seg[:, None, :], axis=2).max(axis=1)
    # the chord of a period that holds a corner (a C0 knot: the engine splits the block and stops there) cuts it
    rep.limit("chord_error", float(np.max(gap[~corner], initial=0.0)), lim["chord_error"])
    end = curve.point(curve.bounds[1])[0]
    rep.limit("end_point_error", float(np.linalg.norm(traj.p[-1] - end)), lim["chord_error"])
    eu = traj.u
    rep.figures["u_end"] = float(eu[-1])
    rep.figures["u_error_raw"] = float(np.max(np.abs(eu - u[1:])))
    rep.figures["u_error_normalised"] = float(np.max(np.abs(eu - (u[1:] - a) / (b - a))))
    bound = nurbs_time_bound(curve, lim)
    rep.figures["time_bound"] = bound
    rep.figures["time_ratio"] = rep.figures["time"] / bound


def _sampled_bound(rep: Report, traj: Trajectory, lim: dict[str, float], P: np.ndarray,
                   line_feed: dict[int, float] | None) -> None:
    pts = np.concatenate([traj.start[None, :], traj.p])
    lines = np.concatenate([[traj.line[0]], traj.line])
    moves = np.concatenate([[traj.move[0]], traj.move])
    step = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    keep = np.concatenate([[True], step > 1e-12])
    pts, lines, moves = pts[keep], lines[keep], moves[keep]
    if len(pts) < 3:
        rep.figures["time_bound"] = 0.0
        return
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    kappa = _menger(pts)
    feed = np.array([min(line_feed.get(int(n), lim["max_feed"]) if line_feed else lim["max_feed"],
                         max(lim["max_feed"], lim["rapid_feed"])) for n in lines])
    vlc = _vlc(kappa, feed, lim, lim["chord_error"])
    vlc[0] = vlc[-1] = 0.0
    # a stop where the direction turns between two blocks
    change = np.nonzero(moves[1:] != moves[:-1])[0]
    for i in change:
        if 1 <= i < len(pts) - 2:
            t0 = pts[i] - pts[i - 1]
            t1 = pts[i + 2] - pts[i + 1]
            cos = np.dot(t0, t1) / (np.linalg.norm(t0) * np.linalg.norm(t1))
            if cos < math.cos(1e-3):
                vlc[i] = 0.0
    bound = _pass_time(s, vlc, lim["acceleration"])
    idle = (traj.feed == 0.0) & (np.linalg.norm(np.diff(np.concatenate([traj.start[None, :], traj.p]), axis=0),
                                                axis=1) <= 1e-12)
    moving_time = float(traj.t[-1]) - float(np.sum(idle)) * lim["period"]
    rep.figures["moving_time"] = moving_time
    rep.figures["time_bound"] = bound
    rep.figures["time_ratio"] = moving_time / bound if bound > 0 else math.nan


# ---------------------------------------------------------------------------------------------------- programs

_WORD = re.compile(r"([A-Z])\s*=?\s*([-+]?(?:\d+\.?\d*|\.\d+))")


def line_feeds(text: str, lim: dict[str, float]) -> dict[int, float]:
    """The highest path speed (m/s) each line of a program may command, scanned in a simple way: the modal F
    (mm/min, inch/min under G20, F * S per revolution under G95), the rapid feed on lines in G0 mode or with a
    canned cycle, G28/G53 (rapids and feeds mixed: the higher of both), capped by ``max_feed``."""
    feed = 0.0
    spindle = 0.0
    rapid_mode = True
    r_values: dict[str, float] = {}
    inch = per_rev = False
    out = {}
    for number, raw in enumerate(text.splitlines(), start=1):
        code = re.sub(r"\([^)]*\)", " ", raw.upper())
        code = code.split(";", 1)[0]
        # Sinumerik R parameters and address=expression (R1=5 R2=R1*2, F=R5*20): evaluated here in a simple way
        for name, expr in re.findall(r"\b(R\d+)=(\S+)", code):
            value = _arith(expr, r_values)
            if value is not None:
                r_values[name] = value
        feed_expr = re.search(r"\bF=(\S+)", code)
        if feed_expr:
            value = _arith(feed_expr.group(1), r_values)
            code = code.replace(feed_expr.group(0), f" F{value} " if value is not None else " ")
        words = _WORD.findall(code.replace("G00", "G0").replace("G01", "G1"))
        gs = {float(v) for letter, v in words if letter == "G"}
        for letter, value in words:
            if letter == "S" and not code.lstrip().startswith("SD"):
                spindle = abs(float(value))
        if 20 in gs:
            inch = True
        if 21 in gs:
            inch = False
        if 95 in gs:
            per_rev = True
        if 94 in gs:
            per_rev = False
        for letter, value in words:
            if letter == "F" and "G4" not in code.split() and not re.search(r"\bG0?4\b", code):
                f = float(value) * (25.4 if inch else 1.0)
                feed = f * spindle if per_rev else f
        mixed = bool(gs & {28.0, 53.0, 73.0, 81.0, 82.0, 83.0, 30.0}) or "CYCLE" in code
        if 0.0 in gs:
            rapid_mode = True
        elif gs & {1.0, 2.0, 3.0, 5.0, 5.1, 5.2, 6.2, 2.0} or "BSPLINE" in code:
            rapid_mode = False
        f_ms = min(feed / 60e3, lim["max_feed"])
        if mixed:
            out[number] = max(f_ms, lim["rapid_feed"])
        else:
            out[number] = lim["rapid_feed"] if rapid_mode else (f_ms if feed > 0 else lim["max_feed"])
    return out


def _arith(expr: str, r_values: dict[str, float]) -> float | None:
    """An arithmetic expression of numbers, R parameters, + - * / and parentheses; None if it is anything else."""
    text = re.sub(r"\bR\d+\b", lambda m: repr(r_values.get(m.group(0), math.nan)), expr)
    if not re.fullmatch(r"[0-9.+\-*/()e ]*(nan)?[0-9.+\-*/()e ]*", text) or not text.strip():
        return None
    try:
        value = float(eval(text, {"__builtins__": {}}, {"nan": math.nan}))  # digits and operators only
    except (SyntaxError, ZeroDivisionError, TypeError):
        return None
    return value if math.isfinite(value) else None


def summary(rep: Report) -> str:
    f = rep.figures
    parts = [f"t={f.get('time', 0):.3f}s", f"ratio={f.get('time_ratio', math.nan):.3f}"]
    for name, measured, bound, ratio in rep.violations:
        parts.append(f"{name}={measured:.4g}>{bound:.4g}(+{ratio * 100:.2f}%)")
    return " ".join(parts)


# ---------------------------------------------------------------------------------------------------- random NURBS

FAMILIES = ("smooth", "rational", "spiral3d", "double_knot", "near_cusp", "tight", "large")
LOOSE_LIMITS = {"acceleration": 5.0, "jerk": 500.0, "centripetal_acceleration": 5.0, "axis_acceleration_x": 10.0,
                "axis_acceleration_y": 10.0, "axis_acceleration_z": 10.0, "axis_jerk_x": 500.0,
                "axis_jerk_y": 500.0, "axis_jerk_z": 500.0}


def _knots(rng, degree: int, n: int, double: bool) -> np.ndarray:
    start = float(rng.choice([0.0, 0.0, -3.0, 2.5, 100.0]))
    length = float(rng.choice([1.0, 1.0, 10.0, 0.25, 37.0]))
    inner = np.sort(rng.uniform(0.05, 0.95, n - degree - 1))
    if double and len(inner) >= 2:
        j = int(rng.integers(0, len(inner) - 1))
        inner[j + 1] = inner[j]
    inner = np.round(inner, 6)
    knots = np.concatenate([np.zeros(degree + 1), inner, np.ones(degree + 1)]) * length + start
    return knots


def _rotation(rng) -> np.ndarray:
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    return q


def random_case(seed: int) -> tuple[str, Nurbs, dict[str, float], str]:
    """A seeded random curve: (family, curve with the values its G-code prints, engine parameters, program)."""
    rng = np.random.default_rng(seed)
    family = FAMILIES[seed % len(FAMILIES)]
    degree = int(rng.integers(2, 6))
    weights = None
    double = False
    if family == "near_cusp":
        # a cubic Bezier hairpin: P0 (0,0), P1 (1,1), P2 (0,1+eps), P3 (1,0) has C'(1/2) = (0, 3 eps / 4)
        degree = 3
        eps = float(rng.choice([0.1, 0.03, 0.01, 0.003]))
        scale = float(rng.uniform(2.0, 20.0))
        pts = np.array([[0, 0, 0], [1, 1, 0], [0, 1 + eps, 0], [1, 0, 0]], float) * scale
        knots = np.array([0, 0, 0, 0, 1, 1, 1, 1], float) * float(rng.choice([1.0, 10.0]))
        n = 4
    else:
        n = degree + 1 + int(rng.integers(0, 9))
        scale = {"tight": rng.uniform(0.3, 2.0), "large": rng.uniform(100.0, 400.0)}.get(family,
                                                                                    rng.uniform(5.0, 50.0))
        steps = rng.normal(size=(n - 1, 3))
        if family not in ("spiral3d",) and rng.random() < 0.6:
            steps[:, 2] = 0.0
        if family == "spiral3d":
            angle = np.linspace(0.0, rng.uniform(2, 4) * math.pi, n)
            radius = float(scale)
            pts = np.column_stack([radius * np.cos(angle), radius * np.sin(angle),
                                   np.linspace(0.0, rng.uniform(-1, 1) * radius, n)])
        else:
            pts = np.concatenate([np.zeros((1, 3)), np.cumsum(steps, axis=0)]) * float(scale) / math.sqrt(n)
        if family in ("rational", "spiral3d") or rng.random() < 0.2:
            weights = rng.uniform(0.3, 3.0, n)
        double = family == "double_knot" or rng.random() < 0.05
        if family == "double_knot" and n - degree - 1 < 2:
            n_extra = 2 - (n - degree - 1)
            pts = np.concatenate([pts, pts[-1] + np.cumsum(rng.normal(size=(n_extra, 3)), axis=0) * scale / 3])
            if weights is not None:
                weights = np.concatenate([weights, rng.uniform(0.3, 3.0, n_extra)])
            n += n_extra
        knots = _knots(rng, degree, n, double)
    if weights is None:
        weights = np.ones(n)
    origin = rng.uniform(-200.0, 200.0, 3)
    rot = _rotation(rng)
    pts = pts @ rot.T + origin
    feed = float(rng.choice([600.0, 1500.0, 3000.0, 6000.0, 12000.0]))
    curve = curve_from_rounded(degree, pts, weights, knots, feed)
    params = dict(LOOSE_LIMITS) if rng.random() < 0.25 else {}
    params.update({f"start_{a}": float(c) for a, c in zip("xyz", curve.points[0])})
    program = "\n".join([f"(random NURBS, seed {seed}, family {family})", "G21 G90 G17"]
                        + curve.gcode(feed) + ["M30", ""])
    return family, curve, params, program


def check_random(seed: int, workdir: Path) -> tuple[str, Nurbs, Report]:
    """Runs the seeded random curve through the C engine and checks it. A run that does not end within
    2 s + 0.3 x its time bound of wall time (the engine writes ~9e4 periods per second: that is a machining time
    above ~25 x the bound) is reported as the violation ``not_finished``."""
    family, curve, params, program = random_case(seed)
    lim = default_limits(**params)
    path = workdir / f"random_{seed}.nc"
    path.write_text(program)
    bound = nurbs_time_bound(curve, lim)
    try:
        traj = run_engine(path, params, workdir=workdir, timeout=2.0 + 0.3 * bound)
    except EngineTimeout:
        rep = Report(figures={"time_bound": bound, "time_ratio": math.inf})
        rep.violations.append(("not_finished", math.inf, bound, math.inf))
        return family, curve, rep
    return family, curve, check(traj, lim, curve=curve)
