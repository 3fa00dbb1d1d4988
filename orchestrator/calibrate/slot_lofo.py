"""Leave-one-feed-out: the standard check of the slot-forces calibration on data the fit did not see.

For every feed of the data folder (at the spec's spindle speed and axial depth) the fit of
:func:`~milling_twin.orchestrator.calibrate.slot_forces.fit_slot` runs on all the other feeds, and the held-out
recording is predicted: its spindle phase is found by the same exhaustive search the fit uses (the phase of a
recording is unknown, a nuisance of every recording), everything else comes from the fit. Per held-out feed:

* the mean-force error per axis, ``(model mean - recorded mean) / |recorded mean|`` over whole revolutions;
* the waveform r^2 per axis of the per-revolution mean waveform, ``1 - SS_res / SS_tot`` (as
  ``orchestrator.validation.slot_milling.waveform_scores``);
* the estimates with their 95 % intervals (the revolution bootstrap of ``[slot_forces].bootstrap``).

Beside the models, what the recordings allow (:mod:`.feed_interpolant`): the same held-out feeds predicted by a
model-free interpolant of the other feeds' waveforms, a polynomial in the feed at every angle. Degree 1 has the
form of every law linear in the chip through any linear measuring chain, with more freedom; degree 2 a law curved
in the chip.

Coverage: for every identified model parameter, the share of ordered pairs of folds (i, j), i != j, whose
estimate i lies inside interval j. When the law and the chain are right and the intervals honest, the folds'
estimates agree within their intervals (coverage near 1); a misfit that repeats every revolution makes the
folds disagree beyond intervals that only know the revolution-to-revolution scatter.
"""
from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Protocol

import numpy as np

from milling_twin import datasets
from milling_twin.orchestrator.calibrate.feed_interpolant import InterpolantFold, interpolant_folds
from milling_twin.orchestrator.calibrate.slot_forces import (PhaseSearch, SlotData, SlotFit, fit_slot, load_slot_data,
                                                            slot_model)
from milling_twin.orchestrator.calibrate.spec import CalibrationSpec
from milling_twin.orchestrator.calibrate.result import Table
from milling_twin.orchestrator.scenario import Scenario
from milling_twin.orchestrator.validation import slot_milling as sm

__all__ = ["Fold", "coverage", "held_out", "leave_one_feed_out", "lofo_tables",
           "recorded_bound", "bound_table"]

AXES = ("Fx", "Fy", "Fz")
BOUND_DEGREES = (1, 2)  # the interpolants beside the models: affine and quadratic in the feed


class Scored(Protocol):
    """A held-out feed's scores: a model's :class:`Fold` or an :class:`InterpolantFold`."""

    held_feed: float
    mean_error: np.ndarray
    r2: np.ndarray


@dataclass
class Fold:
    """One held-out feed: the errors of its prediction and the fit on the other feeds."""

    held_feed: float
    learning_feeds: tuple[float, ...]
    mean_error: np.ndarray  # relative, signed, per recorded axis
    r2: np.ndarray  # per recorded axis
    names: list[str]  # model parameters ("instance.variable")
    estimates: np.ndarray  # SI
    ci: np.ndarray  # parameters x 2, SI
    identified: list[bool]  # not flagged "not identifiable" / "no effect" / at a bound
    fit_time: float
    display: list[tuple[str, float]] = field(default_factory=list)  # (unit, factor) per parameter
    waves: tuple[np.ndarray, np.ndarray] | None = None  # recorded and predicted waveform (points x 3)


def held_out(fit: SlotFit, scenario: Scenario, spec: CalibrationSpec, recording: datasets.Recording,
             n_flutes: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(mean error, r2, recorded waveform, predicted waveform) of a recording the fit did not see."""
    data = SlotData([recording], spec.slot_forces.revolutions, n_flutes)
    model = slot_model(scenario, spec, [recording], [len(data.waves[0])])
    theta = fit.waveform.theta[:fit.model.n_model]
    weights = np.sqrt(fit.waveform.weights) / fit.waveform.sigma
    search = PhaseSearch(model, data)
    phase = search.phase(theta, weights, 0)
    fine = model.fine_waveform(theta, 0, sm.FINE)
    wave = data.waves[0]
    points = len(wave)
    start = int(round(phase / (2 * math.pi) * sm.FINE))
    predicted = fine[(start + np.arange(points) * (sm.FINE // points)) % sm.FINE]
    recorded_mean, predicted_mean = wave.mean(axis=0), predicted.mean(axis=0)
    r2, _ = sm.waveform_scores(wave, predicted)
    return (predicted_mean - recorded_mean) / np.abs(recorded_mean), np.array(r2), wave, predicted


def _feeds(spec: CalibrationSpec, recordings: Sequence[datasets.Recording]) -> list[float]:
    """The feeds of the recordings at the spindle speed and axial depth of the spec's first learning feed."""
    first = next(r for r in recordings if r.feed == spec.slot_forces.learning_feeds[0])
    return sorted(r.feed for r in recordings if r.rpm == first.rpm and r.axial_depth == first.axial_depth)


def recorded_bound(spec: CalibrationSpec, folder: Path, n_flutes: int) -> dict[int, list[InterpolantFold]]:
    """Per degree of :data:`BOUND_DEGREES`: leave one feed out with the feed interpolant of the recorded
    waveforms (the feeds :func:`leave_one_feed_out` holds out, the same revolutions)."""
    recordings = datasets.read_recordings(folder)
    feeds = _feeds(spec, recordings)
    data = SlotData([next(r for r in recordings if r.feed == f) for f in feeds], spec.slot_forces.revolutions, n_flutes)
    return {degree: interpolant_folds(data.waves, feeds, degree) for degree in BOUND_DEGREES
            if degree < len(feeds) - 1}


def _identified(flags: Sequence[str]) -> bool:
    return not any(f.startswith(("not identifiable", "no effect", "at lower", "at upper")) for f in flags)


def leave_one_feed_out(spec: CalibrationSpec, scenario: Scenario, folder: Path, n_flutes: int,
                       progress: Callable[[str], None] | None = None) -> list[Fold]:
    """One fold per feed of ``folder`` at the spindle speed and axial depth of the spec's learning feeds."""
    recordings = datasets.read_recordings(folder)
    feeds = _feeds(spec, recordings)
    folds = []
    for held_feed in feeds:
        learning = tuple(f for f in feeds if f != held_feed)
        fold_spec = replace(spec, slot_forces=replace(spec.slot_forces, learning_feeds=learning,
                                                      validation_feeds=(held_feed,)))
        t0 = time.perf_counter()
        learn = load_slot_data(folder, learning, "[slot_forces].learning_feeds", fold_spec,
                               spec.slot_forces.revolutions, n_flutes)
        fit = fit_slot(fold_spec, scenario, learn, n_flutes)
        elapsed = time.perf_counter() - t0
        recording = next(r for r in recordings if r.feed == held_feed)
        error, r2, wave, predicted = held_out(fit, scenario, fold_spec, recording, n_flutes)
        params = fit.model_parameters
        stats = fit.waveform.statistics.parameters[:len(params)]
        folds.append(Fold(held_feed, learning, error, r2, [q.name for q in params],
                          np.array([s.estimate for s in stats]), np.array([[s.ci_low, s.ci_high] for s in stats]),
                          [_identified(s.flags) for s in stats], elapsed,
                          [(q.display_unit, q.display_factor) for q in params], (wave, predicted)))
        if progress is not None:
            progress(f"held out {held_feed:g} mm/min: mean error "
                     + " / ".join(f"{100 * e:+.1f}" for e in error) + " %, r2 "
                     + " / ".join(f"{v:.3f}" for v in r2) + f" ({elapsed:.1f} s)")
    return folds


def coverage(folds: Sequence[Fold]) -> dict[str, float]:
    """Per parameter identified in every fold: the share of ordered fold pairs (i, j), i != j, with estimate i
    inside interval j (module text)."""
    out = {}
    for k, name in enumerate(folds[0].names):
        if not all(f.identified[k] for f in folds):
            continue
        hits = [folds[j].ci[k, 0] <= folds[i].estimates[k] <= folds[j].ci[k, 1]
                for i in range(len(folds)) for j in range(len(folds)) if i != j]
        out[name] = float(np.mean(hits)) if hits else math.nan
    return out


def summary(folds: Sequence[Scored]) -> dict[str, object]:
    """Mean |mean-force error| and mean r2 per axis over the folds, the worst fold's mean |error| over axes."""
    errors = np.abs(np.array([f.mean_error for f in folds]))
    r2 = np.array([f.r2 for f in folds])
    worst = int(np.argmax(errors.mean(axis=1)))
    return {"mean_abs_error": errors.mean(axis=0).tolist(), "mean_r2": r2.mean(axis=0).tolist(),
            "worst_fold_feed": folds[worst].held_feed, "worst_fold_error": float(errors[worst].mean()),
            "worst_axis_error": float(errors.max())}


def _score_rows(folds: Sequence[Scored]) -> list[tuple[str, str, str]]:
    """(held-out feed, mean-force errors, r2) per fold, then their means: the rows both reports' tables share."""
    s = summary(folds)
    return ([(f"{f.held_feed:g} mm/min", " / ".join(f"{100 * e:+.1f}" for e in f.mean_error),
              " / ".join(f"{v:.3f}" for v in f.r2)) for f in folds]
            + [("mean |error|, mean r2", " / ".join(f"{100 * e:.1f}" for e in s["mean_abs_error"]),
                " / ".join(f"{v:.3f}" for v in s["mean_r2"]))])


def bound_table(bound: dict[int, list[InterpolantFold]]) -> Table:
    """The report's table of :func:`recorded_bound`: per held-out feed, each interpolant's scores."""
    names = {1: "affine in the feed", 2: "quadratic in the feed"}
    rows = []
    for degree, folds in bound.items():
        name = names.get(degree, f"degree {degree} in the feed")
        rows += [(name, *row) for row in _score_rows(folds)]
    return Table("What the recordings allow: each feed predicted from the others' waveforms, angle by angle",
                 ("interpolant", "held-out feed", "mean-force error Fx / Fy / Fz [%]", "waveform r2 Fx / Fy / Fz"),
                 tuple(rows), "No model: every harmonic of the other feeds' per-revolution waveforms (brought to one "
                              "phase) a least-squares polynomial in the feed. Any law linear in the chip through any "
                              "linear measuring chain is affine in the feed at every angle (while both flutes cut): "
                              "where the affine interpolant misses a target, such a model is not to be expected to "
                              "reach it.")


def lofo_tables(folds: Sequence[Fold], label: str) -> list[Table]:
    """The report's tables: per held-out feed, and the coverage of the intervals."""
    rows = [(*row, f"{f.fit_time:.1f}" if f is not None else "")
            for row, f in zip(_score_rows(folds), [*folds, None])]
    s = summary(folds)
    cov = coverage(folds)
    cov_rows = []
    for k, name in enumerate(folds[0].names):
        unit, factor = folds[0].display[k]
        values = ", ".join(f"{f.estimates[k] * factor:.4g} [{f.ci[k, 0] * factor:.4g}, {f.ci[k, 1] * factor:.4g}]"
                           for f in folds)
        cov_rows.append((name, unit, values, f"{100 * cov[name]:.0f} %" if name in cov else "not identified"))
    return [Table(f"Leave one feed out ({label}): prediction of each feed from the others",
                  ("held-out feed", "mean-force error Fx / Fy / Fz [%]", "waveform r2 Fx / Fy / Fz", "fit [s]"),
                  tuple(rows), f"Worst fold: {s['worst_fold_feed']:g} mm/min, mean |error| over the axes "
                               f"{100 * s['worst_fold_error']:.1f} %. Recorded axes (Fx cross-feed, Fy feed)."),
            Table(f"Leave one feed out ({label}): estimates per fold with 95 % intervals, and coverage",
                  ("parameter", "unit", "per fold (held-out feed ascending): estimate [interval]",
                   "coverage (estimate of a fold inside the interval of another)"), tuple(cov_rows),
                  "Intervals from the revolution bootstrap. Phases are per recording and not compared.")]
