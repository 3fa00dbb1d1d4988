"""Synthetic recovery: data made by the FMUs with known parameters plus noise, fitted back.

For a spec of kind "scenario": the scenario is simulated once with the initial values (the
calibration's own run) and once with the true values; the true outputs at the recorded times plus
Gaussian noise (one seed per repeat) replace the recorded channels, and the fit runs on the learning
pairs with one solver built for all repeats. Each repeat says, per parameter, whether the truth lies
in the 95 % interval and the relative error of the estimate.
"""
from __future__ import annotations

import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from milling_twin.orchestrator.calibrate.fit import FitOutcome, fit
from milling_twin.orchestrator.calibrate.lsq import LeastSquaresSolver
from milling_twin.orchestrator.calibrate.pairing import LEARNING
from milling_twin.orchestrator.calibrate.scenario_fit import Prepared, pairs_for, prepare
from milling_twin.orchestrator.calibrate.spec import CalibrationSpec
from cases.calibration_synthetic import truth_outputs, with_channels

__all__ = ["RecoveryRun", "RecoveryStudy"]


@dataclass(frozen=True)
class RecoveryRun:
    seed: int | None  # None: noise-free
    estimates: np.ndarray
    ci_low: np.ndarray
    ci_high: np.ndarray
    identifiable: np.ndarray  # bool per parameter (no identifiability or bound flag)
    covered: np.ndarray  # truth inside the 95 % interval
    relative_error: np.ndarray  # |estimate - truth| / |truth|
    converged: bool
    wall_time: float
    outcome: FitOutcome


class RecoveryStudy:
    """One spec, one truth: :meth:`run` fits one noisy (or noise-free) data set."""

    def __init__(self, spec: CalibrationSpec, fmu_dir: Path, out_dir: Path, truth: Mapping[str, float]) -> None:
        self.spec = spec
        self.prepared: Prepared = prepare(spec, fmu_dir, out_dir)
        names = [q.name for q in self.prepared.parameters]
        unknown = sorted(set(truth) - set(names))
        if unknown or len(truth) != len(names):
            raise ValueError(f"truth must give every fitted parameter ({', '.join(names)}); got {sorted(truth)}")
        self.truth = np.array([truth[n] for n in names])
        rec = self.prepared.scenario.recorded
        outputs = [o.column for o in self.prepared.outputs]
        self.clean = truth_outputs(self.prepared.scenario, dict(truth), outputs, rec.time, out_dir / "truth")
        self.recorded = rec
        pairs, _, _ = pairs_for(self.prepared, self._recording(np.zeros_like(self.clean)))
        self.learning = pairs.select(LEARNING)
        self.model = self.prepared.residual_model(self.learning)
        self.solver = LeastSquaresSolver(self.model.problem, max_iterations=spec.solver.max_iterations,
                                         tolerance=spec.solver.tolerance, hessian=spec.solver.hessian)

    def _recording(self, noise: np.ndarray):
        channels = {}
        for k, o in enumerate(self.prepared.outputs):
            channels[o.channel] = (self.clean[:, k] + noise[:, k]) / o.factor
        return with_channels(self.recorded, channels)

    def run(self, sigma: Sequence[float], seed: int | None) -> RecoveryRun:
        """Fit data with noise of standard deviation ``sigma`` per output (SI; seed None: none)."""
        t0 = time.perf_counter()
        noise = (np.zeros_like(self.clean) if seed is None else
                 np.random.default_rng(seed).normal(0.0, 1.0, self.clean.shape) * np.asarray(sigma)[None, :])
        pairs, _, _ = pairs_for(self.prepared, self._recording(noise))
        learning = pairs.select(LEARNING)
        outcome = fit(self.model, learning.recorded, weights=[o.weight for o in self.prepared.outputs],
                      sigma=[None] * len(self.prepared.outputs), solver=self.spec.solver,
                      statistics=self.spec.statistics, lsq=self.solver)
        st = outcome.statistics.parameters
        low = np.array([p.ci_low for p in st])
        high = np.array([p.ci_high for p in st])
        return RecoveryRun(seed, outcome.theta, low, high, np.array([p.identifiable for p in st]),
                           (self.truth >= low) & (self.truth <= high),
                           np.abs(outcome.theta - self.truth) / np.abs(self.truth),
                           outcome.best.converged, time.perf_counter() - t0, outcome)

    def repeats(self, sigma: Sequence[float], seeds: Sequence[int], progress: bool = False) -> list[RecoveryRun]:
        return [self.run(sigma, s) for s in tqdm(seeds, desc="recovery repeats", disable=not progress)]
