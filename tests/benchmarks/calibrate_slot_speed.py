"""Slot-forces fit time on all five feeds: what one BLAS thread and the force's map in threads each give.

    .venv/bin/python tests/benchmarks/calibrate_slot_speed.py [--data DIR] [--fmu-dir build/fmus]
        [--variants linear,exponential,power_edge,linear+chain,exponential+chain,power_edge+chain]
        [--rounds 1] [--starts 2] [--out runs/benchmarks/calibrate_slot_speed]

Every variant (chip-thickness law, with or without a chain of 2 modes; as ``calibrate_slot_lofo.py`` builds them)
is fitted on the five slot-milling recordings (../shared/data/slot_milling_forces, read from there) in three
set-ups, one after the other in each round, so that the machine's load falls on all three alike:

* ``before``: numpy's BLAS with its own thread count in the Levenberg-Marquardt iterations, the force's map in
  one thread (the solver as it was);
* ``one BLAS thread``: the iterations on one BLAS thread (``models/blas_threads.py``), the map in one thread;
* ``now``: one BLAS thread and the map in ``slot_model.map_threads()`` threads (what a fit does).

Printed per fit: wall time, the process's CPU time, and a hash of the estimates (the three set-ups give the same
numbers to the bit). The JSON is written after every fit (a killed run keeps the finished ones).
"""
from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import time
from dataclasses import replace

from calibrate_slot_lofo import SPEC, slot_arguments, variant_scenario
from milling_twin import datasets
from milling_twin.orchestrator.calibrate import lsq, slot_forces
from milling_twin.orchestrator.calibrate.slot_model import map_threads
from milling_twin.orchestrator.calibrate.spec import load_spec
from milling_twin.orchestrator.validation import slot_milling as sm

SETUPS = ("before", "one BLAS thread", "now")


@contextlib.contextmanager
def setup(name: str):  # type: ignore[no-untyped-def]
    """The solver's BLAS switch and the model's map threads as ``name`` has them."""
    switch, model_of = lsq.one_blas_thread, slot_forces.slot_model
    threads = map_threads() if name == "now" else 1
    if name == "before":
        lsq.one_blas_thread = contextlib.nullcontext
    slot_forces.slot_model = lambda *args, **kwargs: replace(model_of(*args, **kwargs), threads=threads)
    try:
        yield threads
    finally:
        lsq.one_blas_thread, slot_forces.slot_model = switch, model_of


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    slot_arguments(parser, "calibrate_slot_speed")
    parser.add_argument("--rounds", type=int, default=1)
    parser.add_argument("--starts", type=int, default=2)
    args = parser.parse_args()
    folder = datasets.data_dir(args.data)
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "calibrate_slot_speed.json"
    base = load_spec(SPEC)
    feeds = tuple(sorted(r.feed for r in datasets.read_recordings(folder)))
    spec = replace(base, solver=replace(base.solver, starts=args.starts),
                   slot_forces=replace(base.slot_forces, learning_feeds=feeds))
    print(f"load average {os.getloadavg()[0]:.2f}; map threads now: {map_threads()}", flush=True)
    rows = []
    for round_ in range(1, args.rounds + 1):
        for variant in args.variants.split(","):
            scenario = variant_scenario(spec, variant, 2, args.fmu_dir)
            n_flutes = sm._n_flutes(scenario)
            data = slot_forces.load_slot_data(folder, feeds, "feeds", spec, spec.slot_forces.revolutions, n_flutes)
            for name in SETUPS:
                with setup(name) as threads:
                    t0, c0 = time.perf_counter(), time.process_time()
                    fit = slot_forces.fit_slot(spec, scenario, data, n_flutes)
                    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
                digest = hashlib.sha256(fit.waveform.theta.tobytes()).hexdigest()[:16]
                rows.append({"round": round_, "variant": variant, "setup": name, "map_threads": threads,
                             "wall_s": wall, "cpu_s": cpu, "estimates_sha256": digest})
                print(f"round {round_} {variant:18s} {name:16s} wall {wall:6.1f} s  cpu {cpu:6.1f} s  "
                      f"estimates {digest}", flush=True)
                tmp = path.with_suffix(".json.tmp")
                tmp.write_text(json.dumps(rows, indent=2))
                os.replace(tmp, path)
    print("\n| variant | before | one BLAS thread | now | before / now | same estimates |")
    print("|---|---:|---:|---:|---:|---|")
    for variant in args.variants.split(","):
        best = {n: min(r["wall_s"] for r in rows if r["variant"] == variant and r["setup"] == n) for n in SETUPS}
        same = len({r["estimates_sha256"] for r in rows if r["variant"] == variant}) == 1
        print(f"| {variant} | {best['before']:.1f} s | {best['one BLAS thread']:.1f} s | {best['now']:.1f} s | "
              f"{best['before'] / best['now']:.2f} | {'yes' if same else 'NO'} |")
    print(f"written: {path}")


if __name__ == "__main__":
    main()
