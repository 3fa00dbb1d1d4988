"""The fuzz targets (tests/fuzz/README.md): every target has its committed corpus replayed by ctest under
AddressSanitizer and UBSan, the generated seeds are those make_seeds.py writes (so they speak the harnesses'
input language), and -- only when clang is installed -- a short libFuzzer run of every target finds nothing."""
from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from fmu_helpers import repo_root

REPO = repo_root()
FUZZ = REPO / "tests" / "fuzz"
BUILD = REPO / "build"
FUZZ_BUILD = REPO / "build-fuzz"
SHORT_RUN_SECONDS = 4  # per target: 18 targets, about a minute of fuzzing in all (plus building them)


def targets() -> list[str]:
    from milling_twin.models import MODELS

    return ["gcode", "forcenet"] + [f"fmi_{name}_fmi{version}" for name in MODELS for version in (2, 3)]


def test_ctest_replays_the_corpus_of_every_target() -> None:
    listing = subprocess.run(["ctest", "-N"], cwd=BUILD, capture_output=True, text=True, check=True).stdout
    for target in targets():
        assert f"fuzz_corpus_{target}" in listing, f"no corpus replay for {target} in ctest"
        assert (BUILD / "tools" / f"fuzz_{target}_replay").is_file(), f"fuzz_{target}_replay not built"
    for folder in ("gcode", "forcenet", "fmi"):
        assert len(list((FUZZ / "corpus" / folder).iterdir())) >= 10, folder


@pytest.mark.parametrize("version", (2, 3))
def test_the_fmi_seeds_reach_step_mode_and_state_restores(version: int) -> None:
    """The seeds speak the harness's language: traced, the lifecycle seed steps and terminates, the states seed
    restores serialized states, the damaged one has its damaged state rejected (FUZZ_FMI_TRACE)."""
    replay = BUILD / "tools" / f"fuzz_fmi_Interpolator_fmi{version}_replay"

    def trace(seed: str) -> str:
        result = subprocess.run([str(replay), str(FUZZ / "corpus" / "fmi" / f"seed_{seed}")], capture_output=True,
                                text=True, timeout=120, env={**os.environ, "FUZZ_FMI_TRACE": "1"})
        assert result.returncode == 0, result.stderr[-4000:]
        return result.stderr

    def calls(text: str, call: str, status: int) -> int:
        return len(re.findall(rf"^{re.escape(call)} +-> {status} ", text, flags=re.M))

    lifecycle = trace("lifecycle")
    assert calls(lifecycle, "ExitInitializationMode", 0) == 2 and calls(lifecycle, "Terminate", 0) == 1
    assert calls(lifecycle, "DoStep", 0) >= 128
    states = trace("states")
    assert calls(states, "DeserializeFMUState", 0) == 2 and calls(states, "SetFMUState", 0) >= 3
    assert calls(states, "DeserializeFMUState (damaged bytes)", 3) == 1


def test_committed_seeds_are_what_make_seeds_writes(tmp_path: Path) -> None:
    sys.path.insert(0, str(FUZZ))
    try:
        import make_seeds
    finally:
        sys.path.pop(0)
    for folder, seeds in (("forcenet", make_seeds.forcenet_seeds()), ("fmi", make_seeds.fmi_seeds())):
        for name, data in seeds.items():
            path = FUZZ / "corpus" / folder / f"seed_{name}"
            assert path.read_bytes() == data, f"{path} is stale: run python tests/fuzz/make_seeds.py"


# One build folder (build-fuzz) for every target, which share objects (an FMU's generated equations serve its
# FMI 2 and FMI 3 targets): the runs go to one pytest-xdist worker, one after the other (`--dist loadgroup`, as
# `make test` runs), so that no two builds write the folder at once and each object is compiled once.
@pytest.mark.xdist_group("libfuzzer")
@pytest.mark.skipif(shutil.which("clang") is None, reason="clang not installed (make fuzz installs it)")
@pytest.mark.parametrize("target", targets())
def test_a_short_libfuzzer_run_finds_nothing(target: str, tmp_path: Path) -> None:
    result = subprocess.run(["sh", str(FUZZ / "run_fuzz.sh"), target, str(SHORT_RUN_SECONDS)], capture_output=True,
                            text=True, timeout=900,
                            env={**os.environ, "FUZZ_OUT": str(tmp_path), "FUZZ_BUILD": str(FUZZ_BUILD),
                                 "PYTHON": sys.executable})
    assert result.returncode == 0, result.stderr[-6000:]
    assert "Done" in result.stderr and "stat::number_of_executed_units" in result.stderr
    assert not list((tmp_path / "artifacts").iterdir())
