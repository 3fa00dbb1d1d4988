"""Unpacked FMUs reused across runs (orchestrator.fmu_cache): once per FMU content, safe against
concurrent runs, bounded, and off on request."""
from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import numpy as np
import pytest

from milling_twin.orchestrator import fmu_cache
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.results import load_results, read_run_info, sha256_of
from milling_twin.orchestrator.scenario import load_scenario


@pytest.fixture
def extracts(monkeypatch, tmp_path):
    """The cache in tmp_path/cache; returns the list of (fmu, folder) fmpy was asked to unzip."""
    monkeypatch.setenv(fmu_cache.CACHE_ENV, str(tmp_path / "cache"))
    calls: list[tuple[str, str]] = []
    real = fmu_cache.extract

    def counting(filename, unzipdir=None):
        folder = real(filename, unzipdir=unzipdir)
        calls.append((str(filename), str(folder)))
        return folder

    monkeypatch.setattr(fmu_cache, "extract", counting)
    return calls


def test_an_unchanged_fmu_is_unpacked_once(make_case, fmu_dir, tmp_path, extracts):
    scenario = load_scenario(make_case(), fmu_dir)
    first = run(scenario, tmp_path / "a", progress=False, stepping="python")
    second = run(scenario, tmp_path / "b", progress=False, stepping="fast")
    assert len(extracts) == 2  # two FMUs, each unzipped by the first run only
    cached = sorted(p.name for p in (tmp_path / "cache").iterdir())
    assert cached == sorted(sha256_of(i.path) for i in scenario.instances)
    assert [f["sha256"] for f in read_run_info(first.run_dir)["fmus"]] == \
           [sha256_of(i.path) for i in scenario.instances]
    np.testing.assert_array_equal(load_results(first.run_dir).to_numpy(), load_results(second.run_dir).to_numpy())


def test_a_rebuilt_fmu_gets_its_own_folder(fmu_dir, tmp_path, extracts):
    fmu = tmp_path / "SpindlePower.fmu"
    shutil.copy(fmu_dir / "SpindlePower.fmu", fmu)
    old = fmu_cache.unpack(fmu, sha256_of(fmu))
    shutil.copy(fmu_dir / "MrrEstimator.fmu", fmu)  # same file name, other content
    new = fmu_cache.unpack(fmu, sha256_of(fmu))
    assert old.folder != new.folder and not old.temporary and not new.temporary
    assert (Path(new.folder) / "binaries").is_dir() and len(extracts) == 2
    assert fmu_cache.unpack(fmu, sha256_of(fmu)) == new and len(extracts) == 2


@pytest.mark.parametrize("value", ["off", ""])
def test_cache_off_unpacks_into_a_temporary_folder_removed_after_the_run(make_case, fmu_dir, tmp_path, extracts,
                                                                          monkeypatch, value):
    monkeypatch.setenv(fmu_cache.CACHE_ENV, value)
    run(load_scenario(make_case(), fmu_dir), tmp_path, progress=False)
    assert len(extracts) == 2 and not any(Path(folder).exists() for _, folder in extracts)


def test_a_run_losing_the_race_uses_the_winners_folder(fmu_dir, tmp_path, extracts, monkeypatch):
    fmu = fmu_dir / "SpindlePower.fmu"
    digest = sha256_of(fmu)
    real_rename = os.rename

    def another_run_first(src, dst):
        shutil.copytree(src, dst)  # the other run renamed its complete folder into place
        real_rename(src, dst)

    monkeypatch.setattr(fmu_cache.os, "rename", another_run_first)
    unpacked = fmu_cache.unpack(fmu, digest)
    assert unpacked.folder == str(tmp_path / "cache" / digest) and (Path(unpacked.folder) / "binaries").is_dir()
    assert [p.name for p in (tmp_path / "cache").iterdir()] == [digest]  # its own temporary folder is gone


def test_least_recently_used_fmus_and_stale_leftovers_are_removed(fmu_dir, tmp_path, extracts):
    root = tmp_path / "cache"
    now = time.time()
    for k in range(fmu_cache.KEEP + 3):
        (root / f"{k:064x}").mkdir(parents=True)
        os.utime(root / f"{k:064x}", (now - 1000 + k, now - 1000 + k))
    (root / ".abc.killed").mkdir()
    os.utime(root / ".abc.killed", (now - 2 * fmu_cache.STALE_SECONDS,) * 2)
    (root / ".def.unzipping").mkdir()  # another run unzipping right now
    unpacked = fmu_cache.unpack(fmu_dir / "SpindlePower.fmu", sha256_of(fmu_dir / "SpindlePower.fmu"))
    left = {p.name for p in root.iterdir()}
    assert Path(unpacked.folder).name in left and ".def.unzipping" in left and ".abc.killed" not in left
    assert len(left) == fmu_cache.KEEP + 1
    assert {f"{k:064x}" for k in range(4)}.isdisjoint(left)  # the oldest went


def test_an_unusable_cache_falls_back_to_a_temporary_folder(fmu_dir, tmp_path, extracts, monkeypatch, caplog):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    monkeypatch.setenv(fmu_cache.CACHE_ENV, str(blocker / "cache"))
    unpacked = fmu_cache.unpack(fmu_dir / "SpindlePower.fmu", "0" * 64)
    try:
        assert unpacked.temporary and (Path(unpacked.folder) / "binaries").is_dir()
        assert "not usable" in caplog.text and str(blocker / "cache") in caplog.text
    finally:
        shutil.rmtree(unpacked.folder)
