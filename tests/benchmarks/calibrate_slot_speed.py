"""Slot-forces fit time on all five feeds: the force model interpreted by casadi's virtual machine, compiled to
machine code (an empty cache: the compilation counted), and compiled with the objects in the cache.

    .venv/bin/python tests/benchmarks/calibrate_slot_speed.py [--data DIR] [--fmu-dir build/fmus]
        [--variants linear,exponential,power_edge,linear+chain,exponential+chain,power_edge+chain]
        [--rounds 1] [--starts 2] [--out runs/benchmarks/calibrate_slot_speed]

Every variant (chip-thickness law, with or without a chain of 2 modes; as ``calibrate_slot_lofo.py`` builds them)
is fitted on the five slot-milling recordings (../shared/data/slot_milling_forces, read from there) in three
set-ups, one after the other in each round, so that the machine's load falls on all three alike:

* ``interpreted``: ``[slot_forces] compile = false``, casadi's virtual machine (the fit as it was before
  ``orchestrator/calibrate/compiled.py``);
* ``compiled, cold``: compiled, with an empty cache of compiled objects (a new temporary folder per variant and round): the
  time includes compiling the force model and its derivatives;
* ``compiled, cached``: compiled again with that cache (what every later fit of the law takes).

All three run the Levenberg-Marquardt iterations on one BLAS thread and the force's map in
``slot_model.map_threads()`` threads.

Printed per fit: wall time, the process's CPU time, and a hash of the estimates (the three set-ups give the same
numbers to the bit). The JSON is written after every fit (a killed run keeps the finished ones).
"""
from __future__ import annotations

import argparse
import contextlib
import hashlib
import json
import os
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from calibrate_slot_lofo import SPEC, slot_arguments, variant_scenario
from milling_twin import datasets
from milling_twin.orchestrator.calibrate import compiled, slot_forces
from milling_twin.orchestrator.calibrate.slot_model import map_threads
from milling_twin.orchestrator.calibrate.spec import load_spec
from milling_twin.orchestrator.validation import slot_milling as sm

SETUPS = ("interpreted", "compiled, cold", "compiled, cached")


@contextlib.contextmanager
def setup(name: str, cache: Path):  # type: ignore[no-untyped-def]
    """The spec's compile switch and the cache of compiled objects as ``name`` has them."""
    saved = os.environ.get(compiled.CACHE_ENV)
    os.environ[compiled.CACHE_ENV] = str(cache)
    try:
        yield name != "interpreted"
    finally:
        if saved is None:
            os.environ.pop(compiled.CACHE_ENV)
        else:
            os.environ[compiled.CACHE_ENV] = saved


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
    print(f"load average {os.getloadavg()[0]:.2f}; map threads: {map_threads()}; compiler: "
          f"{compiled.find_compiler()}", flush=True)
    rows = []
    for round_ in range(1, args.rounds + 1):
        for variant in args.variants.split(","):
            scenario = variant_scenario(spec, variant, 2, args.fmu_dir)
            n_flutes = sm._n_flutes(scenario)
            data = slot_forces.load_slot_data(folder, feeds, "feeds", spec, spec.slot_forces.revolutions, n_flutes)
            cache = Path(tempfile.mkdtemp(prefix="calibrate_slot_speed_"))
            for name in SETUPS:
                with setup(name, cache) as compile_:
                    fit_spec = replace(spec, slot_forces=replace(spec.slot_forces, compile=compile_))
                    t0, c0 = time.perf_counter(), time.process_time()
                    fit = slot_forces.fit_slot(fit_spec, scenario, data, n_flutes)
                    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
                digest = hashlib.sha256(fit.waveform.theta.tobytes()).hexdigest()[:16]
                rows.append({"round": round_, "variant": variant, "setup": name, "wall_s": wall, "cpu_s": cpu,
                             "estimates_sha256": digest})
                print(f"round {round_} {variant:18s} {name:17s} wall {wall:6.1f} s  cpu {cpu:6.1f} s  "
                      f"estimates {digest}", flush=True)
                tmp = path.with_suffix(".json.tmp")
                tmp.write_text(json.dumps(rows, indent=2))
                os.replace(tmp, path)
    print("\n| variant | interpreted | compiled, cold | compiled, cached | interpreted / cached | same estimates |")
    print("|---|---:|---:|---:|---:|---|")
    for variant in args.variants.split(","):
        best = {n: min(r["wall_s"] for r in rows if r["variant"] == variant and r["setup"] == n) for n in SETUPS}
        same = len({r["estimates_sha256"] for r in rows if r["variant"] == variant}) == 1
        print(f"| {variant} | {best['interpreted']:.1f} s | {best['compiled, cold']:.1f} s | "
              f"{best['compiled, cached']:.1f} s | {best['interpreted'] / best['compiled, cached']:.2f} | "
              f"{'yes' if same else 'NO'} |")
    print(f"written: {path}")


if __name__ == "__main__":
    main()
