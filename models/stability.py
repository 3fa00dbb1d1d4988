"""Stability lobes of milling: Altintas and Budak's zero-order (average tooth-passing) solution.

Given the cutting coefficients, the tool's modes (the same modal parameters as the ToolVibration
FMU) and the radial immersion, this gives the limiting axial depth of cut a_lim over spindle
speed. References: Y. Altintas, E. Budak, "Analytical prediction of stability lobes in milling",
CIRP Annals 44(1), 1995; Y. Altintas, Manufacturing Automation, 2nd ed., Cambridge University
Press 2012, section 3.4.

Conventions as in the cutting-force model: feed along x, immersion angle phi measured clockwise
from the y axis, slotting is phi = 0..pi.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Mode:
    """One mode at the tool tip: natural frequency [Hz], damping ratio [1], modal stiffness [N/m]."""

    frequency: float
    damping: float
    stiffness: float


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
    with np.errstate(divide="ignore", invalid="ignore"):
        if np.allclose(a0, 0):
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
