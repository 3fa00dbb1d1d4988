"""Training of the interpolator's RBF-network parameter predictor (method 3 of the Interpolator FMU).

The predictor (models/interpolator/param_update.py ``predict``, fmus/interpolator/param_update.c) computes, for the next
scheduled step L along a NURBS block,

    u(i+1) = u(i) + D * (1 + N(x)),

- D = L u' + L^2 u''/2 + L^3 u'''/6: the Taylor step with u' and u'' from the curve's derivatives at u(i)
  and u''' from the history, (u''(i) - u''(i-1)) / |C(u(i)) - C(u(i-1))|;
- N: a 4-5-1 Gaussian RBF network, N(x) = b + sum_j w_j exp(-|x - c_j|^2 / (2 sigma^2)), sigma = 1.5, whose
  inputs are the three previous parameters and the step, as features (u(i) - u(i-2), u(i) - u(i-1),
  position of u(i) in the block, L), each normalised to [0, 1] on the training samples (x = (r - offset) *
  scale).
The first three points of a block come from second-order Taylor (the history is not there yet).

Training (this module), on samples of the same curve: the curve is interpolated with the predictor-corrector
to 1e-12 (the exact parameters for the scheduled steps) at several feed overrides; each step gives the
features from the exact history and the target y = (u(i+1) - u(i)) / D - 1, the relative error of D. Then,
as in the method, full-batch gradient descent with momentum (learning rate 0.5, momentum 0.5) on the mean
squared error over centres, output weights and bias (targets standardised, widths fixed at 1.5); and, as an
improvement, the output weights and bias refitted in closed form (linear least squares, centres fixed).

    milling-twin train rbf scenarios/nurbs/butterfly.nc --param start_x=0.054493 \\
        --param start_y=0.052139 --param acceleration=1 --param jerk=100 ... (the benchmark's limits) \\
        --out scenarios/nurbs/butterfly_rbf_weights.toml

writes the weights as FMU parameters (a TOML table for a scenario's [fmus.<name>.parameters]).
"""
from __future__ import annotations

import argparse
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from milling_twin.models import interpolator as ip

LEARNING_RATE = 0.5
MOMENTUM = 0.5
WIDTH = 1.5
EPOCHS = 3000
OVERRIDES = (0.5, 0.75, 1.0, 1.25, 1.5)


@dataclass
class Samples:
    raw: np.ndarray      # (n, 4) features before normalisation
    base: np.ndarray     # (n,) D, the history-augmented Taylor step
    target: np.ndarray   # (n,) the exact step u(i+1) - u(i)

    @property
    def y(self) -> np.ndarray:
        return self.target / self.base - 1.0


class _Recorder(ip.Interpolator):
    """The reference interpolator, exact (corrector to 1e-12), recording each NURBS step's inputs."""

    def __init__(self, text: str, parameters: Mapping[str, float]):
        super().__init__(text, {**parameters, "method": 4, "corrector_predictor": 2, "corrector_tolerance": 1e-12})
        self.samples: list[tuple[float, ...]] = []
        self._zero = ip.Rbf(1.5, (0.0,) * 4, (1.0,) * 4, ((0.0,) * 4,) * 5, (0.0,) * 5, 0.0)

    def nurbs_advance(self, st, curve, m, step, lo, hi):
        u_before = st.u
        record = st.count >= 3 and st.chord_prev > 0.0
        if record:
            base = ip.predict(st, step, ip.METHOD_RBF, self._zero, m.u0, m.u1)
            raw = ip.rbf_features(st.u2, st.u1, st.u, step, m.u0, m.u1)
        super().nurbs_advance(st, curve, m, step, lo, hi)
        if record and st.u < m.u1 and base > 0.0:
            self.samples.append((*raw, base, st.u - u_before))


def collect(text: str, parameters: Mapping[str, float], overrides: Sequence[float] = OVERRIDES) -> Samples:
    rows: list[tuple[float, ...]] = []
    for override in overrides:
        rec = _Recorder(text, parameters)
        rec.set_override(override, 0.0)
        while not rec.finished:
            rec.tick()
        rows += rec.samples
    a = np.array(rows)
    return Samples(a[:, :4], a[:, 4], a[:, 5])


def normalisation(raw: np.ndarray, extent: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """offset and scale mapping each feature's training range onto [0, extent]."""
    lo, hi = raw.min(axis=0), raw.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    return lo, extent / span


def _phi(x: np.ndarray, centers: np.ndarray, width: float) -> np.ndarray:
    d2 = np.sum((x[:, None, :] - centers[None, :, :]) ** 2, axis=2)
    return np.exp(-d2 / (2.0 * width * width))


@dataclass
class Network:
    offset: np.ndarray
    scale: np.ndarray
    centers: np.ndarray   # (5, 4)
    weights: np.ndarray   # (5,)
    bias: float
    width: float = WIDTH

    def __call__(self, raw: np.ndarray) -> np.ndarray:
        x = (raw - self.offset) * self.scale
        return self.bias + _phi(x, self.centers, self.width) @ self.weights

    def parameters(self) -> dict[str, float]:
        p = {"rbf_width": float(self.width)}
        for d in range(4):
            p[f"rbf_offset_{d + 1}"] = float(self.offset[d])
            p[f"rbf_scale_{d + 1}"] = float(self.scale[d])
        for j in range(5):
            for d in range(4):
                p[f"rbf_center_{j + 1}_{d + 1}"] = float(self.centers[j, d])
            p[f"rbf_weight_{j + 1}"] = float(self.weights[j])
        p["rbf_bias"] = float(self.bias)
        return p


def train(samples: Samples, epochs: int = EPOCHS, least_squares: bool = True,
          extent: float = 1.0) -> tuple[Network, dict[str, float]]:
    """Gradient descent with momentum (the method), then (least_squares) the closed-form output weights."""
    offset, scale = normalisation(samples.raw, extent)
    x = (samples.raw - offset) * scale
    y = samples.y
    mean, std = float(y.mean()), float(y.std()) or 1.0
    yn = (y - mean) / std
    # centres: samples at the quantiles of the position in the block (deterministic)
    order = np.argsort(x[:, 2])
    centers = x[order[np.linspace(0, len(x) - 1, 7).astype(int)[1:-1]]].copy()
    weights = np.zeros(5)
    bias = 0.0
    velocity = [np.zeros_like(centers), np.zeros(5), 0.0]
    n = len(x)
    for _ in range(epochs):
        phi = _phi(x, centers, WIDTH)
        err = bias + phi @ weights - yn
        grad_w = phi.T @ err / n
        grad_b = float(err.mean())
        # d phi_j / d c_j = phi_j (x - c_j) / width^2
        coef = (err[:, None] * phi) * weights[None, :] / (WIDTH * WIDTH)
        grad_c = (coef[:, :, None] * (x[:, None, :] - centers[None, :, :])).sum(axis=0) / n
        velocity[0] = MOMENTUM * velocity[0] - LEARNING_RATE * grad_c
        velocity[1] = MOMENTUM * velocity[1] - LEARNING_RATE * grad_w
        velocity[2] = MOMENTUM * velocity[2] - LEARNING_RATE * grad_b
        centers = centers + velocity[0]
        weights = weights + velocity[1]
        bias = bias + velocity[2]
    phi = _phi(x, centers, WIDTH)
    rms_gd = float(np.sqrt(np.mean((bias + phi @ weights - yn) ** 2)))
    if least_squares:
        design = np.column_stack([phi, np.ones(n)])
        solution, *_ = np.linalg.lstsq(design, yn, rcond=None)
        weights, bias = solution[:5], float(solution[5])
    rms_ls = float(np.sqrt(np.mean((bias + phi @ weights - yn) ** 2)))
    net = Network(offset, scale, centers, weights * std, bias * std + mean)
    report = {"samples": float(n), "target_rms": float(np.sqrt(np.mean(y ** 2))),
              "rms_gradient_descent": rms_gd * std, "rms_least_squares": rms_ls * std}
    return net, report


def load_weights(path: Path) -> dict[str, float]:
    """The rbf_* parameters of a weights file written by this module (TOML, table [parameters])."""
    with open(path, "rb") as f:
        data = tomllib.load(f)
    return {k: float(v) for k, v in data["parameters"].items()}


def write_weights(path: Path, net: Network, report: Mapping[str, float], source: str) -> None:
    lines = ["# RBF predictor weights for the Interpolator FMU (method 3), trained by milling_twin/training/rbf.py",
             f"# on {source}: {int(report['samples'])} steps; relative error of the base step (rms) "
             f"{report['target_rms']:.3e}, after the network: gradient descent {report['rms_gradient_descent']:.3e}, "
             f"least squares {report['rms_least_squares']:.3e}.",
             "[parameters]"]
    lines += [f"{k} = {v!r}" for k, v in net.parameters().items()]
    path.write_text("\n".join(lines) + "\n")


def command(args: argparse.Namespace) -> int:
    """``milling-twin train rbf PROGRAM --param name=value ... --out FILE``."""
    params = {}
    for item in args.param:
        name, sep, value = item.partition("=")
        try:
            params[name.strip()] = float(value)
        except ValueError:
            raise ValueError(f"--param {item!r}: expected NAME=VALUE with a number in SI units") from None
        if not sep:
            raise ValueError(f"--param {item!r}: expected NAME=VALUE")
    samples = collect(args.program.read_text(), params)
    net, report = train(samples, args.epochs or EPOCHS)
    write_weights(args.out, net, report, args.program.name)
    for k, v in report.items():
        print(f"{k}: {v:.6g}")
    print(f"wrote {args.out}")
    return 0
