"""Every FMI 2 FMU through FMI4j, the JVM importer (Maven Central ``info.laht.fmi4j:fmi-import``; its own native
bridge loads the FMU, not fmpy): the same random parameters and inputs as the libcosim check of
tests/test_fmu_compliance.py, stepped with a fixed step by the driver of tests/importers/fmi4j/, give the outputs
fmpy gives to 1e-9 relative.

The driver is built once per session into a temporary folder (``mvn -o package`` when ~/.m2 holds every
artifact, else online); the tests skip when java or mvn is missing or Maven Central cannot be reached.
"""
from __future__ import annotations

import csv
import fcntl
import os
import shutil
import subprocess
import urllib.error
import urllib.request
from pathlib import Path

import numpy as np
import pytest

from fmu_helpers import (
    all_fmus,
    assert_close,
    fmu_id,
    model_of,
    numeric_parameters,
    output_names,
    random_arguments,
    reference_trajectory,
    repo_root,
    require_fmu,
    scalar_inputs,
    split_fmu_name,
)
from test_fmu_compliance import _fmpy_steps

PROJECT = repo_root() / "tests" / "importers" / "fmi4j"
ARTIFACT = "https://repo.maven.apache.org/maven2/info/laht/fmi4j/fmi-import/0.38.0/fmi-import-0.38.0.pom"
FMI2_FMUS = [p for p in all_fmus() if split_fmu_name(p)[1] == 2]
STEP_SIZE = 1e-3
RTOL = 1e-9


def maven_central_reachable(timeout: float = 10.0) -> bool:
    try:
        with urllib.request.urlopen(urllib.request.Request(ARTIFACT, method="HEAD"), timeout=timeout) as reply:
            return reply.status == 200
    except (urllib.error.URLError, OSError):
        return False


def build_driver(build_dir: Path) -> Path:
    """``mvn package`` of tests/importers/fmi4j into ``build_dir``: offline first, online when the local
    repository lacks an artifact. Returns the driver's jar; skips when Maven cannot get its artifacts."""
    for tool in ("java", "mvn"):
        if shutil.which(tool) is None:
            pytest.skip(f"FMI4j tests need `{tool}` on PATH (a JDK >= 11 and Maven)")
    command = ["mvn", "-q", "-B", "-f", str(PROJECT / "pom.xml"), "package", f"-DbuildDir={build_dir}"]
    offline = subprocess.run(command[:3] + ["-o"] + command[3:], capture_output=True, text=True)
    if offline.returncode != 0:
        if not maven_central_reachable():
            pytest.skip(f"Maven Central ({ARTIFACT}) is unreachable and the local Maven repository lacks "
                        f"FMI4j or a build plugin: {offline.stdout[-300:]}")
        online = subprocess.run(command, capture_output=True, text=True)
        assert online.returncode == 0, f"mvn package of {PROJECT} failed:\n{online.stdout}\n{online.stderr}"
    jar = build_dir / "fmi4j-driver.jar"
    assert jar.is_file(), f"mvn package of {PROJECT} made no {jar}"
    return jar


@pytest.fixture(scope="session")
def fmi4j_driver(tmp_path_factory) -> Path:
    """Built once per run: under pytest-xdist the workers share one build (the first one to take the lock builds,
    the others wait and reuse its jar) in the run's common temporary folder."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        return build_driver(tmp_path_factory.mktemp("fmi4j-build"))
    root = tmp_path_factory.getbasetemp().parent
    with (root / "fmi4j-build.lock").open("w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        build_dir = root / "fmi4j-build"
        jar = build_dir / "fmi4j-driver.jar"
        return jar if jar.is_file() else build_driver(build_dir)


@pytest.fixture(params=FMI2_FMUS, ids=fmu_id)
def fmu2(request) -> Path:
    return require_fmu(request.param)


def plan_value(model, name: str, value: float) -> str:
    """A value as the driver parses it: integers for Int32 and Boolean, repr (exact) for Float64."""
    return str(int(value)) if model.variable(name).type in ("Int32", "Boolean") else repr(float(value))


def write_plan(path: Path, model, starts: dict[str, float], inputs: list[dict[str, float]],
               step_size: float) -> None:
    lines = [f"step_size,{step_size!r}", f"steps,{len(inputs)}"]
    lines += [f"start,{name},{plan_value(model, name, value)}" for name, value in starts.items()]
    lines += [f"input,{k},{name},{plan_value(model, name, value)}"
              for k, point in enumerate(inputs) for name, value in point.items()]
    path.write_text("\n".join(lines) + "\n")


def java_environment() -> dict[str, str]:
    """The environment of the driver's JVM. Under the sanitizer stage (tests/run_sanitized.sh preloads ASan into
    every process) FMI4j's own JNI library, not instrumented, releases with free() the loader it allocated with
    new (its fmi2.cpp, see docs/importers.md): ASan's alloc-dealloc-mismatch check is turned off for the JVM only,
    so that the instrumented FMU is still checked in full."""
    env = dict(os.environ)
    if "LD_PRELOAD" in env and "ASAN_OPTIONS" in env:
        env["ASAN_OPTIONS"] += ":alloc_dealloc_mismatch=0"
    return env


def run_java(driver: Path, fmu: Path, plan: Path, out: Path) -> subprocess.CompletedProcess:
    """The driver on one FMU. The JVM's temporary folder is the output's: FMI4j extracts each FMU's binary into a
    ``fmi4j_dll*`` folder there and leaves the folder behind, which in the system's /tmp piles up run after run."""
    scratch = out.parent / "java-tmp"
    scratch.mkdir(exist_ok=True)
    return subprocess.run(["java", f"-Djava.io.tmpdir={scratch}", "-jar", str(driver), str(fmu), str(plan), str(out)],
                          capture_output=True, text=True, timeout=300, env=java_environment())


def run_fmi4j(driver: Path, fmu: Path, plan: Path, out: Path) -> tuple[list[str], np.ndarray]:
    """Runs the driver; returns the header and the rows (time first) as floats."""
    done = run_java(driver, fmu, plan, out)
    assert done.returncode == 0, f"FMI4j driver on {fmu.name} failed ({done.returncode}): {done.stderr}"
    with out.open(newline="") as f:
        rows = list(csv.reader(f))
    return rows[0], np.array([[float(x) for x in r] for r in rows[1:]], dtype=float)


def columns_of(model, header: list[str]) -> list[int]:
    """The CSV columns of the model's outputs in the order fmu_helpers.Slave.get returns them: a scalar by
    name, an FMI 2 array by its elements "name[i,j]" in model description order."""
    columns: list[int] = []
    for name in output_names(model):
        found = [i for i, h in enumerate(header) if h == name or h.startswith(name + "[")]
        assert found, f"output {name} is not in the FMI4j driver's output header {header}"
        columns += found
    return columns


def max_relative_difference(actual: np.ndarray, expected: np.ndarray) -> float:
    """Largest |actual - expected| relative to max(|expected|, its column's largest magnitude), the measure of
    fmu_helpers.assert_close."""
    scale = np.maximum(np.abs(expected), np.max(np.abs(expected), axis=0, keepdims=True))
    error = np.abs(actual - expected)
    return float(np.max(np.where(scale > 0, error / np.where(scale > 0, scale, 1.0), error)))


def test_plan_value_writes_exact_floats_and_integers() -> None:
    class Variable:
        def __init__(self, kind: str):
            self.type = kind

    class Model:
        def variable(self, name: str) -> Variable:
            return Variable({"b": "Boolean", "i": "Int32"}.get(name, "Float64"))

    assert plan_value(Model(), "x", 0.1 + 0.2) == "0.30000000000000004"
    assert float(plan_value(Model(), "x", np.pi)) == np.pi
    assert plan_value(Model(), "b", 1.0) == "1" and plan_value(Model(), "i", 7.0) == "7"


def test_driver_names_the_plan_line_of_an_unknown_variable(fmi4j_driver: Path, tmp_path: Path) -> None:
    fmu = require_fmu(FMI2_FMUS[0])
    plan = tmp_path / "plan.csv"
    plan.write_text("step_size,0.001\nsteps,1\nstart,no_such_variable,1\n")
    done = run_java(fmi4j_driver, fmu, plan, tmp_path / "out.csv")
    assert done.returncode == 1
    assert f"{plan}:3: the FMU has no variable 'no_such_variable'" in done.stderr


def test_driver_refuses_an_fmi3_fmu_by_name(fmi4j_driver: Path, tmp_path: Path) -> None:
    """FMI4j 0.38 has no FMI 3 import (an importer limit, see docs/importers.md)."""
    identifier, _ = split_fmu_name(FMI2_FMUS[0])
    fmu = require_fmu(FMI2_FMUS[0].with_name(f"{identifier}.fmu"))
    plan = tmp_path / "plan.csv"
    plan.write_text("step_size,0.001\nsteps,1\n")
    done = run_java(fmi4j_driver, fmu, plan, tmp_path / "out.csv")
    assert done.returncode == 1
    assert f"{fmu}: FMI4j cannot import it" in done.stderr and "3.0" in done.stderr


def test_fmi2_fmu_runs_in_fmi4j_like_in_fmpy(fmi4j_driver: Path, fmu2: Path, tmp_path: Path) -> None:
    model = model_of(fmu2)
    values = random_arguments(model, 12, np.random.default_rng(11))
    parameters = {v.name: float(values[v.name][5]) for v in numeric_parameters(model)}
    inputs = [{v.name: float(values[v.name][i]) for v in scalar_inputs(model)} for i in range(2, 12)]
    plan = tmp_path / "plan.csv"
    write_plan(plan, model, {**parameters, **inputs[0]}, inputs, STEP_SIZE)

    header, rows = run_fmi4j(fmi4j_driver, fmu2, plan, tmp_path / "out.csv")
    assert header[0] == "time" and rows.shape[0] == len(inputs)
    assert rows[:, 0] == pytest.approx(STEP_SIZE * np.arange(1, len(inputs) + 1), rel=1e-12)
    fmi4j = rows[:, columns_of(model, header)]

    reference = _fmpy_steps(fmu2, parameters, inputs, STEP_SIZE)
    assert np.all(np.isfinite(fmi4j))
    assert_close(fmi4j, reference, rtol=RTOL,
                 what=f"FMI4j vs fmpy (max relative difference {max_relative_difference(fmi4j, reference):.3g})")
    assert_close(fmi4j, reference_trajectory(model, [{**parameters, **p} for p in inputs], STEP_SIZE))
