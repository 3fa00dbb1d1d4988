"""The G-code parser's fuzz harness (tests/fuzz/): the committed corpus replays under AddressSanitizer and
UBSan without a report, and — only when clang is installed — a short libFuzzer run finds nothing."""
from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from fmu_helpers import repo_root

REPO = repo_root()
REPLAY = REPO / "build" / "tools" / "fuzz_gcode_replay"
CORPUS = REPO / "tests" / "fuzz" / "corpus"


def test_the_corpus_replays_under_the_sanitizers() -> None:
    assert REPLAY.is_file(), f"{REPLAY} not built (cmake --build build)"
    files = sorted(CORPUS.iterdir())
    assert len(files) >= 40
    result = subprocess.run([str(REPLAY), str(CORPUS)], capture_output=True, text=True, timeout=300,
                            env={**os.environ, "ASAN_OPTIONS": "detect_leaks=1:abort_on_error=1"})
    assert result.returncode == 0, result.stderr[-4000:]
    assert f"replayed {len(files)} inputs without a crash" in result.stdout
    assert "runtime error" not in result.stderr and "AddressSanitizer" not in result.stderr


@pytest.mark.skipif(shutil.which("clang") is None, reason="clang not installed (make fuzz installs it)")
def test_a_short_libfuzzer_run_finds_nothing(tmp_path: Path) -> None:
    result = subprocess.run(["sh", str(REPO / "tests" / "fuzz" / "run_fuzz.sh"), "20"], capture_output=True,
                            text=True, timeout=600, env={**os.environ, "FUZZ_OUT": str(tmp_path)})
    assert result.returncode == 0, result.stderr[-4000:]
    assert "Done" in result.stderr and "stat::number_of_executed_units" in result.stderr
    assert not list((tmp_path / "artifacts").iterdir())
