"""Every FMU built with AddressSanitizer and UndefinedBehaviorSanitizer (-DFMU_SANITIZE=ON, build-asan/),
driven through a full simulation and the rejected calls in a subprocess with the sanitizer runtime
preloaded: no sanitizer report, exit code 0, and the same outputs as the model.

Leak detection is off here (the Python interpreter's own allocations would drown the report); leaks
are covered by valgrind in ctest and by test_fmu_lifecycle.py."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import (
    assert_close,
    expected_fmus,
    points_of,
    reference_trajectory,
    model_of,
    output_names,
    random_arguments,
    repo_root,
)

BUILD_DIR = repo_root() / "build-asan"
# The module's fixture configures and builds build-asan: its tests go to one pytest-xdist worker (`make test` runs
# --dist loadgroup), or two workers would configure the new folder at once (cmake fails on the other's files).
pytestmark = pytest.mark.xdist_group("build-asan")
SANITIZER_REPORTS = ("ERROR: AddressSanitizer", "ERROR: LeakSanitizer", "runtime error:",
                     "SUMMARY: UndefinedBehaviorSanitizer")


def gcc_runtime(name: str) -> str:
    path = subprocess.run(["gcc", f"-print-file-name={name}"], check=True, capture_output=True,
                          text=True).stdout.strip()
    assert os.path.isabs(path) and os.path.isfile(path), f"gcc has no {name} (got {path!r})"
    return path


def run(command: list[str], **kwargs) -> subprocess.CompletedProcess:
    result = subprocess.run(command, capture_output=True, text=True, **kwargs)
    assert result.returncode == 0, f"{' '.join(command)} failed:\n{result.stdout[-4000:]}\n{result.stderr[-4000:]}"
    return result


@pytest.fixture(scope="module")
def sanitized_fmus() -> list[Path]:
    """Configure (or reuse) build-asan with FMU_SANITIZE=ON and build only the FMU targets."""
    from milling_twin.models import MODELS

    run(["cmake", "-S", str(repo_root()), "-B", str(BUILD_DIR), "-DFMU_SANITIZE=ON",
         f"-DPython3_EXECUTABLE={sys.executable}"])
    targets = [f"{identifier}_fmi{version}" for identifier in MODELS for version in (2, 3)]
    run(["cmake", "--build", str(BUILD_DIR), "-j2", "--target", *targets], timeout=600)
    fmus = expected_fmus(BUILD_DIR / "fmus")
    missing = [p.name for p in fmus if not p.is_file()]
    assert not missing, f"not built in {BUILD_DIR}: {missing}"
    cache = (BUILD_DIR / "CMakeCache.txt").read_text()
    assert "FMU_SANITIZE:BOOL=ON" in cache
    return fmus


def test_fmus_are_instrumented(sanitized_fmus: list[Path]) -> None:
    for fmu in sanitized_fmus:
        identifier = fmu.name.removesuffix(".fmu").removesuffix("_fmi2")
        platform = "linux64" if fmu.name.endswith("_fmi2.fmu") else "x86_64-linux"
        version = 2 if fmu.name.endswith("_fmi2.fmu") else 3
        library = BUILD_DIR / "fmu_staging" / f"{identifier}_fmi{version}" / "binaries" / platform / f"{identifier}.so"
        needed = run(["readelf", "-d", str(library)]).stdout
        assert "libasan.so" in needed and "libubsan.so" in needed, f"{library} is not instrumented"


def test_full_simulation_and_bad_calls_under_asan_and_ubsan(sanitized_fmus: list[Path], tmp_path: Path) -> None:
    job = {"fmus": {}}
    for fmu in sanitized_fmus:
        model = model_of(fmu)
        values = random_arguments(model, 300, np.random.default_rng(17))
        job["fmus"][str(fmu)] = {"values": {k: v.tolist() for k, v in values.items()},
                                 "outputs": output_names(model)}
    job_file = tmp_path / "job.json"
    job_file.write_text(json.dumps(job))

    env = dict(os.environ)
    env.update(
        # the interpreter is not instrumented: the ASan runtime must come first; UBSan's is loaded with it
        LD_PRELOAD=" ".join([gcc_runtime("libasan.so"), gcc_runtime("libubsan.so")]),
        ASAN_OPTIONS="detect_leaks=0:abort_on_error=1:halt_on_error=1",
        UBSAN_OPTIONS="halt_on_error=1:print_stacktrace=1",
        PYTHONPATH=os.pathsep.join([str(repo_root()), str(Path(__file__).parent)]),
        PYTHONDONTWRITEBYTECODE="1",
    )
    result = subprocess.run([sys.executable, str(Path(__file__).parent / "fmu_helpers.py"), str(job_file)],
                            env=env, capture_output=True, text=True, timeout=300, cwd=tmp_path)
    reports = [marker for marker in SANITIZER_REPORTS if marker in result.stderr]
    assert not reports, f"sanitizer reports {reports}:\n{result.stderr[-8000:]}"
    assert result.returncode == 0, f"exit code {result.returncode}:\n{result.stdout[-2000:]}\n{result.stderr[-8000:]}"
    assert f"exercised {len(sanitized_fmus)} FMUs" in result.stdout

    results = json.loads(job_file.read_text())["results"]
    assert set(results) == set(job["fmus"])
    for path, spec in job["fmus"].items():
        model = model_of(path)
        values = {k: np.array(v) for k, v in spec["values"].items()}
        assert_close(np.array(results[path]["outputs"]), reference_trajectory(model, points_of(values), 1e-3), what=path)
        errors = results[path]["errors"]
        assert any("illegal call sequence" in e for e in errors), errors
        assert any("out of its allowed range" in e for e in errors), errors
        assert any("must be a finite number" in e for e in errors), errors
        assert any("unknown value reference" in e for e in errors), errors
        assert any("does not match the instance time" in e for e in errors), errors
        assert any("serialized FMUstate has" in e for e in errors), errors
