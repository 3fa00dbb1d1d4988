"""Stability lobes of milling: Altintas and Budak's zero-order (average tooth-passing) solution, and
Insperger and Stepan's semi-discretization as the time-domain reference.

Given the cutting coefficients, the tool's modes (the same modal parameters as the ToolVibration
FMU) and the radial immersion, this gives the limiting axial depth of cut a_lim over spindle
speed. References: Y. Altintas, E. Budak, "Analytical prediction of stability lobes in milling",
CIRP Annals 44(1), 1995; Y. Altintas, Manufacturing Automation, 2nd ed., Cambridge University
Press 2012, section 3.4; T. Insperger, G. Stepan, "Updated semi-discretization method for periodic
delay-differential equations with discrete delay", Int. J. Numer. Meth. Engng 61 (2004) 117-141.

Conventions as in the cutting-force model: feed along x, immersion angle phi measured clockwise
from the y axis, slotting is phi = 0..pi.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass

import numpy as np

from milling_twin.models.blas_threads import one_blas_thread


@dataclass(frozen=True)
class Mode:
    """One mode at the tool tip: natural frequency [Hz], damping ratio [1], modal stiffness [N/m]."""

    frequency: float
    damping: float
    stiffness: float


def ring_down_time(modes: Iterable[Mode], fraction: float) -> float:
    """The time (s) in which the free response of ``modes`` falls to ``fraction`` of its amplitude: that of the
    slowest envelope exp(-sigma t), sigma = zeta omega for an underdamped mode, omega (zeta - sqrt(zeta^2 - 1))
    for an overdamped one; inf if a mode has no damping, 0 for no modes."""
    slowest = math.inf
    for m in modes:
        omega, zeta = 2.0 * math.pi * m.frequency, m.damping
        slowest = min(slowest, zeta * omega if zeta <= 1.0 else omega * (zeta - math.sqrt(zeta * zeta - 1.0)))
    if slowest == math.inf:
        return 0.0
    return math.log(1.0 / fraction) / slowest if slowest > 0.0 else math.inf


def frf(modes: tuple[Mode, ...], omega: np.ndarray) -> np.ndarray:
    """Direct FRF at the tool tip [m/N] at angular frequencies omega [rad/s]: sum of the modes."""
    result = np.zeros_like(omega, dtype=complex)
    for m in modes:
        wn = 2 * math.pi * m.frequency
        result += (wn ** 2 / m.stiffness) / (wn ** 2 - omega ** 2 + 2j * m.damping * wn * omega)
    return result


def directional_factors(entry: float, exit: float, kr: float) -> tuple[float, float, float, float]:
    """Average directional factors (alpha_xx, alpha_xy, alpha_yx, alpha_yy) over the immersion."""

    def primitive(phi: float) -> tuple[float, float, float, float]:
        s2, c2 = math.sin(2 * phi), math.cos(2 * phi)
        return (0.5 * (c2 - 2 * kr * phi + kr * s2), 0.5 * (-s2 - 2 * phi + kr * c2),
                0.5 * (-s2 + 2 * phi + kr * c2), 0.5 * (-c2 - 2 * kr * phi - kr * s2))

    high, low = primitive(exit), primitive(entry)
    return tuple(h - l for h, l in zip(high, low))  # type: ignore[return-value]


@dataclass(frozen=True)
class Lobes:
    """Lobe curves: lobe k at chatter frequencies ``chatter_frequency`` [Hz] has spindle speeds
    ``speed[k]`` [rpm] and limiting depths ``depth`` [m] (the same for every lobe)."""

    chatter_frequency: np.ndarray
    depth: np.ndarray
    speed: np.ndarray  # (lobes, frequencies)

    def limit(self, speed_rpm: float | np.ndarray) -> np.ndarray:
        """Limiting axial depth [m] at the given spindle speeds: the lowest lobe there."""
        speeds = np.atleast_1d(np.asarray(speed_rpm, dtype=float))
        best = np.full(speeds.shape, np.inf)
        valid = np.isfinite(self.depth) & (self.depth > 0)
        for lobe in self.speed:
            n, a = lobe[valid], self.depth[valid]
            order = np.argsort(n)
            n, a = n[order], a[order]
            inside = (speeds >= n[0]) & (speeds <= n[-1])
            best[inside] = np.minimum(best[inside], np.interp(speeds[inside], n, a))
        return best


def stability_lobes(modes_x: tuple[Mode, ...], modes_y: tuple[Mode, ...], ktc: float, krc: float,
                    n_flutes: int, entry: float = 0.0, exit: float = math.pi, lobes: int = 12,
                    points: int = 4000) -> Lobes:
    """Zero-order stability lobes. ``ktc``, ``krc`` in N/m^2; entry/exit immersion angles in rad."""
    kr = krc / ktc
    axx, axy, ayx, ayy = directional_factors(entry, exit, kr)
    frequencies = [m.frequency for m in modes_x + modes_y]
    f_chatter = np.linspace(0.5 * min(frequencies), 1.6 * max(frequencies), points)
    omega = 2 * math.pi * f_chatter
    gx = frf(modes_x, omega) if modes_x else np.zeros_like(omega, dtype=complex)
    gy = frf(modes_y, omega) if modes_y else np.zeros_like(omega, dtype=complex)
    a0 = gx * gy * (axx * ayy - axy * ayx)
    a1 = axx * gx + ayy * gy
    # One eigenvalue when only one direction is flexible or the directional matrix is singular. Decided from
    # the structure, never from the size of a0: a0 is in m^2/N^2 (~1e-11 for a 2e7 N/m tool), and an absolute
    # tolerance there dropped the coupled solution for stiff tools (a limit 4.7 times too high at 2800 Hz).
    determinant = axx * ayy - axy * ayx
    single = not modes_x or not modes_y or abs(determinant) <= 1e-12 * max(abs(axx), abs(axy), abs(ayx),
                                                                             abs(ayy)) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        if single:
            eigenvalues = [-1.0 / a1]
        else:
            root = np.sqrt(a1 ** 2 - 4 * a0)
            eigenvalues = [-(a1 + root) / (2 * a0), -(a1 - root) / (2 * a0)]
        depths = []
        for lam in eigenvalues:
            kappa = lam.imag / lam.real
            depths.append(-2 * math.pi * lam.real / (n_flutes * ktc) * (1 + kappa ** 2))
        depths_array = np.array(depths)
        depths_array[~(depths_array > 0)] = np.inf  # only positive depths are physical
        choice = np.argmin(depths_array, axis=0)
        depth = depths_array[choice, np.arange(len(omega))]
        lam = np.choose(choice, eigenvalues)
        kappa = lam.imag / lam.real
        epsilon = math.pi - 2 * np.arctan(kappa)
        speeds = np.array([60.0 / (n_flutes * (epsilon + 2 * k * math.pi) / omega) for k in range(lobes)])
    depth[~np.isfinite(depth)] = np.nan
    return Lobes(chatter_frequency=f_chatter, depth=depth, speed=speeds)


# --- Semi-discretization (time domain, no averaging over the tooth period) -----------------------------------
#
# Insperger and Stepan's first-order semi-discretization (Int. J. Numer. Meth. Engng 61 (2004) 117-141;
# "Semi-Discretization for Time-Delay Systems", Springer 2011). The tool's modes in modal coordinates,
# state y = (q_1, dq_1/dt, ..., q_n, dq_n/dt), tip displacement r = C y = (x, y). The linear chip law of the
# zero-order solution without the averaging over the tooth period:
#     dy/dt = A y + a Ktc P W(t) (r(t) - r(t - tau)),   W(t) = sum_j g_j w(phi_j(t)),
# with w(phi) the coefficients of Fx, Fy in the regenerated chip (half the integrands of directional_factors),
# g_j = 1 while flute j is in the immersion, tau the tooth period (the period of W as well). Each of the m
# steps of tau keeps W at its mean over the step (exact integrals of w), solves the ODE part exactly
# (matrix exponential) and interpolates the delayed displacement linearly between its two neighbouring
# samples. The map over one tooth period (the monodromy matrix) acts on the present state and the m
# delayed displacements; the cut is asymptotically stable when its spectral radius is below 1.


def _modal_state_space(modes_x: tuple[Mode, ...], modes_y: tuple[Mode, ...]
                       ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, P, C): dy/dt = A y + P F for the modes in x then y (modal mass k / wn^2), r = C y."""
    modes = [(m, 0) for m in modes_x] + [(m, 1) for m in modes_y]
    size = 2 * len(modes)
    a, p, c = np.zeros((size, size)), np.zeros((size, 2)), np.zeros((2, size))
    for i, (m, axis) in enumerate(modes):
        wn = 2 * math.pi * m.frequency
        a[2 * i, 2 * i + 1] = 1.0
        a[2 * i + 1, 2 * i] = -wn ** 2
        a[2 * i + 1, 2 * i + 1] = -2 * m.damping * wn
        p[2 * i + 1, axis] = wn ** 2 / m.stiffness
        c[axis, 2 * i] = 1.0
    return a, p, c


def step_directional_matrices(n_flutes: int, kr: float, entry: float, exit: float, steps: int) -> np.ndarray:
    """W averaged over each of ``steps`` equal steps of the tooth period, shape (steps, 2, 2): the force per unit
    depth and Ktc is W (r(t) - r(t - tau)). Flute j is at phi = 2 pi (i / (N m) + j / N) at the start of step i."""
    width = 2 * math.pi / (n_flutes * steps)
    result = np.zeros((steps, 2, 2))
    for i in range(steps):
        for j in range(n_flutes):
            low = i * width + 2 * math.pi * j / n_flutes
            high = low + width
            for turn in range(int(math.floor((low - exit) / (2 * math.pi))),
                              int(math.floor((high - entry) / (2 * math.pi))) + 1):
                lo, hi = max(low, entry + 2 * math.pi * turn), min(high, exit + 2 * math.pi * turn)
                if hi > lo:
                    result[i] += 0.5 * np.reshape(directional_factors(lo, hi, kr), (2, 2))
    return result / width


@dataclass(frozen=True)
class SemiDiscretization:
    """The per-step matrices of one cut (tool, coefficients, immersion, speed); ``spectral_radius(depth)``."""

    a: np.ndarray  # (d, d) modal state matrix
    p: np.ndarray  # (d, 2) force -> state derivative
    c: np.ndarray  # (2, d) state -> tip displacement
    pw: np.ndarray  # (m, d, 2) Ktc P W_i per step
    dt: float  # step [s]

    @classmethod
    def build(cls, modes_x: tuple[Mode, ...], modes_y: tuple[Mode, ...], ktc: float, krc: float, n_flutes: int,
              speed_rpm: float, entry: float = 0.0, exit: float = math.pi, steps: int | None = None
              ) -> "SemiDiscretization":
        if not modes_x and not modes_y:
            raise ValueError("semi-discretization: no modes in x or y")
        if n_flutes < 1 or speed_rpm <= 0 or not 0 < exit - entry <= 2 * math.pi:
            raise ValueError(f"semi-discretization: n_flutes={n_flutes}, speed_rpm={speed_rpm}, entry={entry}, "
                             f"exit={exit} (need n_flutes >= 1, speed > 0, 0 < exit - entry <= 2 pi)")
        for axis, modes in (("x", modes_x), ("y", modes_y)):
            for k, m in enumerate(modes):
                if not (m.frequency > 0 and m.stiffness > 0 and m.damping >= 0):
                    raise ValueError(f"semi-discretization: mode {k + 1} in {axis} {m} (need frequency > 0, "
                                     "stiffness > 0, damping >= 0)")
        tau = 60.0 / (n_flutes * speed_rpm)
        immersion = (exit - entry) * n_flutes / (2 * math.pi)
        m = steps if steps is not None else default_steps(modes_x + modes_y, tau, immersion)
        if m < 2:
            raise ValueError(f"semi-discretization: steps={m} (need >= 2)")
        a, p, c = _modal_state_space(modes_x, modes_y)
        w = step_directional_matrices(n_flutes, krc / ktc, entry, exit, m)
        return cls(a=a, p=p, c=c, pw=ktc * np.einsum("dk,ikl->idl", p, w), dt=tau / m)

    @property
    def steps(self) -> int:
        return self.pw.shape[0]

    def monodromy(self, depth: float) -> np.ndarray:
        """The map over one tooth period of (y_i, r_{i-1}, ..., r_{i-m}), square of size d + 2 m."""
        d, m, dt = self.a.shape[0], self.steps, self.dt
        coupling = depth * self.pw  # (m, d, 2)
        phi, gamma0, gamma1 = _step_exponentials(self.a + coupling @ self.c, dt)
        # y_{i+1} = Phi_i y_i - (Gamma0 - Gamma1) a Ktc P W_i r_{i-m} - Gamma1 a Ktc P W_i r_{i-m+1}
        oldest = -(gamma0 - gamma1) @ coupling
        newer = -gamma1 @ coupling
        size = d + 2 * m
        y = np.eye(d, size)  # rows of y_i in terms of the initial vector
        delayed = [np.eye(2, size, k=d + 2 * k) for k in range(m)]  # rows of r_{i-1-k}
        start = 0  # delayed[(start + k) % m] holds r_{i-1-k}
        for i in range(m):
            r_oldest = delayed[(start + m - 1) % m]
            r_newer = delayed[(start + m - 2) % m]
            y_next = phi[i] @ y + oldest[i] @ r_oldest + newer[i] @ r_newer
            start = (start - 1) % m
            delayed[start] = self.c @ y
            y = y_next
        return np.vstack([y] + [delayed[(start + k) % m] for k in range(m)])

    def spectral_radius(self, depth: float) -> float:
        with one_blas_thread():
            return float(np.max(np.abs(np.linalg.eigvals(self.monodromy(depth)))))


def _step_exponentials(a: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For each step's A (shape (m, d, d)): Phi = exp(A dt), Gamma0 = int_0^dt exp(A (dt - s)) ds and
    Gamma1 = int_0^dt exp(A (dt - s)) s / dt ds, from the eigen-decomposition (batched, vectorised); a step whose
    eigenvectors are ill-conditioned takes the exponential of the block matrix [[A, I, 0], [0, 0, I/dt], [0, 0, 0]]
    dt instead (Van Loan)."""
    eigenvalues, vectors = np.linalg.eig(a)
    condition = np.linalg.cond(vectors)
    good = np.isfinite(condition) & (condition < 1e8)
    x = eigenvalues * dt
    small = np.abs(x) < 1e-3
    safe = np.where(small, 1.0, x)
    g0 = np.where(small, 1 + x / 2 + x ** 2 / 6, np.expm1(safe) / safe) * dt
    g1 = np.where(small, 0.5 + x / 6 + x ** 2 / 24, (np.expm1(safe) - safe) / safe ** 2) * dt
    inverse = np.linalg.inv(np.where(good[:, None, None], vectors, np.eye(a.shape[1])))

    def combine(values: np.ndarray) -> np.ndarray:
        return np.real(np.einsum("mij,mj,mjk->mik", vectors, values, inverse))

    phi, gamma0, gamma1 = combine(np.exp(x)), combine(g0), combine(g1)
    if not np.all(good):
        from scipy.linalg import expm  # scipy only for this rare case

        d = a.shape[1]
        bad = np.flatnonzero(~good)
        blocks = np.zeros((len(bad), 3 * d, 3 * d))
        blocks[:, :d, :d] = a[bad]
        blocks[:, :d, d:2 * d] = np.eye(d)
        blocks[:, d:2 * d, 2 * d:] = np.eye(d) / dt
        exponentials = expm(blocks * dt)
        phi[bad], gamma0[bad], gamma1[bad] = (exponentials[:, :d, :d], exponentials[:, :d, d:2 * d],
                                              exponentials[:, :d, 2 * d:])
    return phi, gamma0, gamma1


def default_steps(modes: tuple[Mode, ...], tau: float, immersion: float = 1.0, per_period: int = 24,
                  per_cut: int = 20, minimum: int = 40, most_for_the_cut: int = 200) -> int:
    """Steps per tooth period: ``per_period`` per period of the highest mode, ``per_cut`` while a flute cuts
    (``immersion``: the cut's share of the tooth period; at most ``most_for_the_cut`` steps for that), at least
    ``minimum``. The limit then moves by < 1 % from m to 2 m steps (docs/models.md)."""
    highest = max(m.frequency for m in modes)
    for_the_cut = min(most_for_the_cut, int(math.ceil(per_cut / min(1.0, max(immersion, 1e-9)))))
    return max(minimum, int(math.ceil(per_period * highest * tau)), for_the_cut)


def _depth_scale(modes_x: tuple[Mode, ...], modes_y: tuple[Mode, ...], ktc: float, n_flutes: int) -> float:
    """Order of magnitude of the limit: Tlusty's 4 k zeta (1 + zeta) / (N Ktc) of the weakest mode."""
    return min(4 * m.stiffness * m.damping * (1 + m.damping) for m in modes_x + modes_y) / (n_flutes * ktc)


def semi_discretization_limit(modes_x: tuple[Mode, ...], modes_y: tuple[Mode, ...], ktc: float, krc: float,
                              n_flutes: int, speed_rpm: float, entry: float = 0.0, exit: float = math.pi,
                              steps: int | None = None, rtol: float = 1e-3, ratio: float = 1.25,
                              max_depth: float | None = None) -> float:
    """Limiting axial depth [m] at one spindle speed: the smallest depth whose monodromy matrix has a spectral
    radius >= 1. Depths rise by ``ratio`` from a fifth of the Tlusty scale until the first unstable one (an
    unstable island narrower than ``ratio`` below it can be missed), then the bracket narrows to ``rtol``
    (:func:`_radius_crossing`). ``inf`` when stable up to ``max_depth`` (default 1000 times that scale)."""
    sd = SemiDiscretization.build(modes_x, modes_y, ktc, krc, n_flutes, speed_rpm, entry, exit, steps)
    scale = _depth_scale(modes_x, modes_y, ktc, n_flutes)
    ceiling = max_depth if max_depth is not None else 1000 * scale
    low, rho_low = 0.0, 0.0
    high = 0.2 * scale
    rho_high = sd.spectral_radius(high)
    while rho_high < 1.0:
        low, rho_low = high, rho_high
        high *= ratio
        if low >= ceiling:
            return math.inf
        rho_high = sd.spectral_radius(high)
    if low == 0.0:  # unstable at the first depth: halve down to a stable one
        low = high / 2
        rho_low = sd.spectral_radius(low)
        while rho_low >= 1.0:
            high, rho_high, low = low, rho_low, low / 2
            if low < 1e-6 * scale:
                return 0.0
            rho_low = sd.spectral_radius(low)
    return _radius_crossing(sd.spectral_radius, low, rho_low, high, rho_high, rtol)


def _radius_crossing(radius: Callable[[float], float], low: float, rho_low: float, high: float, rho_high: float,
                     rtol: float) -> float:
    """The depth where ``radius`` crosses 1 between a stable ``low`` and an unstable ``high`` (their radii
    given), as the middle of a bracket narrower than ``rtol`` times its upper end, as bisection would give it.
    False position on log(radius) with the Illinois rule (the end that stays has its value halved), each
    estimate kept a quarter of the tolerance inside the bracket so that a converged estimate closes it from its
    other side; a bisection step after every estimate that did not halve the bracket, so that a radius far from
    log-linear (a kink where the dominant eigenvalue changes) costs at most twice bisection. About 5 radii
    instead of bisection's 8 from a bracket of 25 %."""
    f_low, f_high = math.log(rho_low), math.log(rho_high)
    kept = 0  # -1: low moved last, +1: high moved last
    width_before = math.inf  # the bracket's width before a false-position step, inf after a bisection
    while high - low > rtol * high:
        if high - low > 0.5 * width_before:  # the last false position did not halve the bracket
            depth = 0.5 * (low + high)
            width_before = math.inf
        else:
            margin = 0.25 * rtol * high
            estimate = (low * f_high - high * f_low) / (f_high - f_low)
            depth = min(max(estimate, low + margin), high - margin)
            width_before = high - low
        value = math.log(radius(depth))
        if value < 0.0:
            low, f_low = depth, value
            if kept == -1:
                f_high *= 0.5
            kept = -1
        else:
            high, f_high = depth, value
            if kept == 1:
                f_low *= 0.5
            kept = 1
    return 0.5 * (low + high)


def semi_discretization_lobes(modes_x: tuple[Mode, ...], modes_y: tuple[Mode, ...], ktc: float, krc: float,
                              n_flutes: int, speeds_rpm: np.ndarray | list[float], entry: float = 0.0,
                              exit: float = math.pi, steps: int | None = None, rtol: float = 1e-3) -> np.ndarray:
    """Limiting axial depths [m] at the given spindle speeds (``semi_discretization_limit`` at each)."""
    return np.array([semi_discretization_limit(modes_x, modes_y, ktc, krc, n_flutes, float(n), entry, exit,
                                               steps, rtol) for n in np.atleast_1d(np.asarray(speeds_rpm, float))])
