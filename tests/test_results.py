"""Incremental results: atomic chunks, run.json, and loading a run that was killed."""
from __future__ import annotations

import json
import random
import signal
import time

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from conftest import LONG_P_TOTAL, LONG_TOML, start_run, wait_for_first_chunk
from milling_twin.orchestrator.results import RunWriter, load_results, read_run_info


def test_writer_chunks_and_run_info(tmp_path):
    run_dir = tmp_path / "run"
    (run_dir / "chunks").mkdir(parents=True)
    (run_dir / "chunks" / "chunk_000009.parquet").write_text("stale")  # from an earlier run
    writer = RunWriter(run_dir, ["time", "a.x", "a.on"], ["a.on"], {"scenario": {"name": "t"}},
                       flush_rows=3, flush_seconds=3600)
    assert read_run_info(run_dir)["status"] == "running"
    assert load_results(run_dir).columns.tolist() == ["time", "a.x", "a.on"]  # no chunk yet
    for i in range(7):
        writer.append([i * 0.5, i * 10.0, i % 2])
    names = sorted(p.name for p in (run_dir / "chunks").iterdir())
    assert names == ["chunk_000001.parquet", "chunk_000002.parquet"]  # 6 rows flushed, no temp files
    writer.finish("completed", steps=7)
    info = read_run_info(run_dir)
    assert info["status"] == "completed" and info["rows_written"] == 7 and info["steps"] == 7
    assert info["scenario"] == {"name": "t"} and info["columns"] == ["time", "a.x", "a.on"]
    assert {"python", "fmpy", "numpy"} <= set(info["versions"])
    assert info["start_wall_time"] <= info["end_wall_time"]
    frame = load_results(run_dir)
    expected = pd.DataFrame({"time": np.arange(7) * 0.5, "a.x": np.arange(7) * 10.0,
                             "a.on": np.arange(7) % 2 == 1})
    pd.testing.assert_frame_equal(frame, expected)
    assert not [p for p in run_dir.rglob("*") if p.name.startswith(".")]


def test_writer_flushes_on_wall_time(tmp_path):
    writer = RunWriter(tmp_path, ["time"], flush_rows=1000, flush_seconds=0.0)
    writer.append([0.0])
    writer.append([1.0])
    assert writer.chunks == 2 and len(load_results(tmp_path)) == 2


def test_load_results_of_a_killed_run(long_run):
    proc, run_dir = long_run
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=10)
    info = json.loads((run_dir / "run.json").read_text())
    assert info["status"] == "running"  # never got to say otherwise
    frame = load_results(run_dir)
    n = len(frame)
    assert n >= 1
    # a consistent prefix: rows 0..n-1 of the output grid, every value complete
    np.testing.assert_allclose(frame["time"].to_numpy(), np.arange(n) * 0.01, rtol=0, atol=1e-9)
    np.testing.assert_array_equal(frame["power.P_total"].to_numpy(), np.full(n, LONG_P_TOTAL))
    assert frame["power.spindle_on"].all()


KILLS_PER_PATH = 3


@pytest.mark.parametrize("stepping", ["python", "fast"])
def test_sigkill_at_random_moments_keeps_every_completed_chunk(stepping, tmp_path, fmu_dir):
    """SIGKILL the CLI at seeded random moments after its first chunk (a row per 1 ms step, so chunks
    of 10,000 rows follow each other quickly and a kill often lands inside a chunk write): every chunk
    on disk just before the kill is still there, loads, and continues the time grid of the chunk
    before it; nothing after it is half there."""
    scenario = tmp_path / "long.toml"
    scenario.write_text(LONG_TOML.replace("output_interval = 0.01", "output_interval = 0.001"))
    rng = random.Random(f"sigkill-{stepping}")
    for attempt in range(KILLS_PER_PATH):
        out = tmp_path / f"kill{attempt}"
        proc = start_run(scenario, fmu_dir, out, "--path", stepping)
        run_dir = out / "runs" / "long"
        try:
            wait_for_first_chunk(proc, run_dir)
            time.sleep(rng.uniform(0.0, 1.0))
            before = sorted(p.name for p in (run_dir / "chunks").glob("chunk_*.parquet"))
            proc.send_signal(signal.SIGKILL)
            proc.wait(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
            proc.communicate()
        info = read_run_info(run_dir)
        assert info["status"] == "running" and info["stepping"]["path"] == stepping  # it never got to finish
        chunks = sorted((run_dir / "chunks").glob("chunk_*.parquet"), key=lambda p: int(p.stem.split("_")[1]))
        names = [p.name for p in chunks]
        assert names[: len(before)] == before, f"attempt {attempt}: chunks lost by the kill"
        assert names == [f"chunk_{i:06d}.parquet" for i in range(1, len(names) + 1)], names
        start = 0
        for path in chunks:  # each chunk complete and continuing the previous one
            frame = pq.read_table(path).to_pandas()
            n = len(frame)
            assert n >= 1 and frame.columns.tolist() == ["time", "power.P_total", "power.spindle_on"]
            np.testing.assert_allclose(frame["time"].to_numpy(), (start + np.arange(n)) * 0.001, rtol=0, atol=1e-9)
            np.testing.assert_array_equal(frame["power.P_total"].to_numpy(), np.full(n, LONG_P_TOTAL))
            assert frame["power.spindle_on"].all()
            start += n
        assert len(load_results(run_dir)) == start  # temporary files of an interrupted write are not read
