"""The package as a user gets it (docs/packaging.md): a wheel with every FMU and the stepper library, tagged with
the glibc its binaries need, installed into a fresh virtual environment at constraints.txt's versions and run with
no CMake or C compiler on PATH, from a folder outside the repository; the FMU lookup that finds the packaged FMUs;
the FMU release tarball."""
from __future__ import annotations

import json
import os
import platform
import re
import shutil
import subprocess
import sys
import tarfile
import zipfile
from pathlib import Path

import pytest

from conftest import REPO_ROOT

sys.path.insert(0, str(REPO_ROOT))  # buildtools/ (the build helpers: not installed)

from buildtools.elf import elf_needs  # noqa: E402
from buildtools.release import ReleaseError, write_release  # noqa: E402
from buildtools.wheel_files import FMUS_ENV, STEPPER_ENV, STEPPER_NAME, WheelFilesError, select  # noqa: E402

COMPILERS = ("cmake", "gcc", "cc", "c++", "g++", "clang", "zig")
# what the wheel is built from: the build inputs (a copy, so that nothing is written into the repository)
WHEEL_SOURCES = ("pyproject.toml", "README.md", "setup.py", "MANIFEST.in", "constraints.txt", "buildtools",
                 "milling_twin", "models", "orchestrator")


def _fmu_dir() -> Path:
    return Path(os.environ.get("MILLING_TWIN_FMU_DIR", REPO_ROOT / "build" / "fmus"))


def _built() -> tuple[Path, Path]:
    """The built FMUs and stepper library (the test command builds them first: missing ones fail)."""
    fmus, stepper = _fmu_dir(), _fmu_dir().parent / "stepper" / STEPPER_NAME
    assert sorted(fmus.glob("*.fmu")), f"{fmus}: no built FMUs (make fmus)"
    assert stepper.is_file(), f"{stepper}: no stepper library (make fmus)"
    return fmus, stepper


def _objdump_glibc(data: bytes, tmp: Path) -> tuple[int, int]:
    path = tmp / "probe.so"
    path.write_bytes(data)
    out = subprocess.run(["objdump", "-T", str(path)], capture_output=True, text=True, check=True).stdout
    return max((int(a), int(b)) for a, b in re.findall(r"GLIBC_(\d+)\.(\d+)", out))


def _newest_glibc(fmus: Path, stepper: Path) -> tuple[int, int]:
    found = [elf_needs(stepper.read_bytes(), str(stepper)).glibc]
    for fmu in fmus.glob("*.fmu"):
        with zipfile.ZipFile(fmu) as archive:
            found += [elf_needs(archive.read(n), n).glibc for n in archive.namelist()
                      if n.endswith(".so") and "linux" in n]
    return max([(2, 17), *(v for v in found if v is not None)])


# --- the binaries' needs --------------------------------------------------------------------------------------

def test_the_elf_reader_finds_what_objdump_finds(tmp_path: Path) -> None:
    if shutil.which("objdump") is None:
        pytest.skip("objdump (binutils) is not installed: nothing to compare the ELF reader with")
    fmus, stepper = _built()
    samples = [("stepper", stepper.read_bytes())]
    with zipfile.ZipFile(fmus / "CuttingForce.fmu") as archive:
        samples += [(n, archive.read(n)) for n in archive.namelist() if n.endswith(".so") and "linux" in n]
    assert len(samples) >= 2
    for name, data in samples:
        needs = elf_needs(data, name)
        assert needs.machine == "x86_64" or needs.machine == "aarch64", name
        assert needs.glibc == _objdump_glibc(data, tmp_path), name


def test_the_wheel_files_are_refused_when_not_built(tmp_path: Path) -> None:
    with pytest.raises(WheelFilesError, match=f"{tmp_path / 'build' / 'fmus'}.*no .fmu files.*{FMUS_ENV}"):
        select(tmp_path, {})
    fmus = tmp_path / "fmus"
    fmus.mkdir()
    (fmus / "SpindlePower.fmu").write_bytes(b"")
    with pytest.raises(WheelFilesError, match=r"missing: SpindlePower_fmi2\.fmu"):
        select(tmp_path, {FMUS_ENV: str(fmus)})
    (fmus / "SpindlePower_fmi2.fmu").write_bytes(b"")
    with pytest.raises(WheelFilesError, match=f"{tmp_path / 'nowhere.so'}.*{STEPPER_ENV}"):
        select(tmp_path, {FMUS_ENV: str(fmus), STEPPER_ENV: str(tmp_path / "nowhere.so")})
    assert not select(tmp_path, {FMUS_ENV: "none"}).native


def test_the_cross_compiled_fmus_are_preferred(tmp_path: Path) -> None:
    for folder in ("fmus", "fmus-all"):
        (tmp_path / "build" / folder).mkdir(parents=True)
        for name in ("Workpiece.fmu", "Workpiece_fmi2.fmu"):
            (tmp_path / "build" / folder / name).write_bytes(b"")
    (tmp_path / "build" / "stepper").mkdir()
    (tmp_path / "build" / "stepper" / STEPPER_NAME).write_bytes(b"")
    files = select(tmp_path, {})
    assert {p.parent.name for p in files.fmus} == {"fmus-all"}
    assert files.stepper == tmp_path / "build" / "stepper" / STEPPER_NAME
    cross = tmp_path / "build" / "fmus-all" / "stepper" / f"{platform.machine()}-linux" / STEPPER_NAME
    cross.parent.mkdir(parents=True)
    cross.write_bytes(b"")
    assert select(tmp_path, {}).stepper == cross  # the cross-compiled library beside the cross-compiled FMUs
    for fmu in (tmp_path / "build" / "fmus-all").glob("*.fmu"):
        fmu.unlink()  # an empty build/fmus-all/ (a cross-compilation under way or failed) is not taken
    assert {p.parent.name for p in select(tmp_path, {}).fmus} == {"fmus"}


# --- the FMU lookup -------------------------------------------------------------------------------------------

def test_the_packaged_fmus_are_the_last_default(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from milling_twin.api import FMU_DIR_ENV, default_fmu_dir
    from milling_twin.orchestrator import packaged

    package = tmp_path / "site" / "milling_twin"
    (package / "fmus").mkdir(parents=True)
    (package / "fmus" / "Workpiece.fmu").write_bytes(b"")
    (package / "stepper").mkdir()
    (package / "stepper" / STEPPER_NAME).write_bytes(b"")
    monkeypatch.setattr(packaged, "_package_dir", lambda: package)
    monkeypatch.delenv(FMU_DIR_ENV, raising=False)
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    assert default_fmu_dir() == package / "fmus"  # no build tree here: the installed package's
    assert packaged.packaged_file("stepper", STEPPER_NAME) == package / "stepper" / STEPPER_NAME
    (work / "build" / "fmus").mkdir(parents=True)
    assert default_fmu_dir() == Path("build/fmus")  # a build tree wins
    monkeypatch.setenv(FMU_DIR_ENV, str(tmp_path / "mine"))
    assert default_fmu_dir() == tmp_path / "mine"  # and the variable over both
    monkeypatch.delenv(FMU_DIR_ENV)
    shutil.rmtree(work / "build")
    (package / "fmus" / "Workpiece.fmu").unlink()
    assert default_fmu_dir() == Path("build/fmus")  # nothing anywhere: errors name build/fmus


# --- the release tarball --------------------------------------------------------------------------------------

def test_the_release_holds_the_fmus_a_readme_and_the_licence(tmp_path: Path) -> None:
    fmus, _ = _built()
    with pytest.raises(ReleaseError, match=str(tmp_path / "LICENSE")):
        write_release(fmus, tmp_path / "LICENSE", tmp_path / "dist", "9.8.7")
    licence = tmp_path / "LICENSE"
    licence.write_text("the licence text\n")
    target = write_release(fmus, licence, tmp_path / "dist", "9.8.7")
    assert target.name == "milling-twin-fmus-9.8.7.tar.gz"
    with tarfile.open(target) as tar:
        names = tar.getnames()
        readme = tar.extractfile("milling-twin-fmus-9.8.7/README.md").read().decode()  # type: ignore[union-attr]
        assert tar.extractfile("milling-twin-fmus-9.8.7/LICENSE").read() == b"the licence text\n"  # type: ignore
    built = sorted(p.name for p in fmus.glob("*.fmu"))
    assert sorted(n.split("/")[1] for n in names if n.endswith(".fmu")) == built
    assert {"README.md", "LICENSE", "THIRD_PARTY.md"} <= {n.split("/")[1] for n in names}
    for name in built:
        assert f"| `{name}` | {'2.0' if name.endswith('_fmi2.fmu') else '3.0'} |" in readme
    major, minor = max(v for v in [elf_needs(d, n).glibc for n, d in _linux_binaries(fmus)] if v is not None)
    assert f"glibc {major}.{minor} or newer" in readme


def _linux_binaries(fmus: Path) -> list[tuple[str, bytes]]:
    found = []
    for fmu in fmus.glob("*.fmu"):
        with zipfile.ZipFile(fmu) as archive:
            found += [(n, archive.read(n)) for n in archive.namelist() if n.endswith(".so") and "linux" in n]
    return found


# --- the wheel, installed and run -----------------------------------------------------------------------------

def _without_compilers(path: str) -> str:
    kept = [d for d in path.split(os.pathsep) if d and not any(shutil.which(t, path=d) for t in COMPILERS)]
    return os.pathsep.join(kept)


def copy_tracked(target: Path) -> None:
    # tracked and new (not ignored) files: the tree as `pip wheel .` sees it, without build/ and caches
    tracked = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", *WHEEL_SOURCES],
                             cwd=REPO_ROOT, capture_output=True, text=True, check=True).stdout.split()
    for name in tracked:
        if (REPO_ROOT / name).is_file():
            (target / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO_ROOT / name, target / name)


def _user_copy(scenario: str, folders: tuple[str, ...], target: Path) -> Path:
    """A shipped scenario and the folders of files it names, copied as a user would (paths inside stay relative
    to the scenario file)."""
    target.mkdir(parents=True)
    shutil.copy2(REPO_ROOT / "scenarios" / scenario, target / scenario)
    for folder in folders:
        shutil.copytree(REPO_ROOT / "scenarios" / folder, target / folder)
    return target / scenario


def test_the_wheel_installs_and_runs_without_a_compiler(tmp_path: Path) -> None:
    fmus, stepper = _built()
    source = tmp_path / "src"
    copy_tracked(source)
    env = {**os.environ, FMUS_ENV: str(fmus), STEPPER_ENV: str(stepper)}
    build = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(tmp_path / "dist"),
                            str(source)], capture_output=True, text=True, env=env, timeout=600)
    assert build.returncode == 0, build.stderr[-3000:]
    (wheel,) = (tmp_path / "dist").glob("milling_twin-*.whl")
    major, minor = _newest_glibc(fmus, stepper)
    assert wheel.name.endswith(f"-py3-none-manylinux_{major}_{minor}_x86_64.whl"), wheel.name
    names = set(zipfile.ZipFile(wheel).namelist())
    assert {f"milling_twin/fmus/{p.name}" for p in fmus.glob("*.fmu")} <= names
    assert f"milling_twin/stepper/{STEPPER_NAME}" in names

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=300)
    # --no-compile: byte-compiling the 1.1 GB of dependencies is half the install's CPU time; what runs compiles
    install = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", "--no-compile",
                              "--disable-pip-version-check", str(wheel), "-c", str(REPO_ROOT / "constraints.txt")],
                             capture_output=True, text=True, timeout=900)
    assert install.returncode == 0, install.stderr[-3000:]

    work = tmp_path / "work"  # outside the repository, no build/ here
    work.mkdir()
    path = _without_compilers(os.environ.get("PATH", ""))
    assert not [t for t in COMPILERS if shutil.which(t, path=path)]
    run_env = {k: v for k, v in os.environ.items()
               if k not in ("MILLING_TWIN_FMU_DIR", "MILLING_TWIN_STEPPER", "PYTHONPATH", "VIRTUAL_ENV", "LD_PRELOAD")}
    run_env["PATH"] = path
    command = str(venv / "bin" / "milling-twin")

    scenario = _user_copy("slot_entry_variable.toml", ("programs",), tmp_path / "user")
    # named relative to the working folder: the program inside resolves against the scenario file
    run = subprocess.run([command, "run", os.path.relpath(scenario, work), "--out", "out", "--no-progress"], cwd=work,
                         env=run_env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout[-2000:] + run.stderr[-3000:]
    assert "completed: 15000 steps" in run.stdout and "fast path" in run.stdout, run.stdout
    meta = json.loads((work / "out" / "slot_entry_variable" / "run.json").read_text())
    site = venv.resolve()
    assert meta["status"] == "completed"
    assert meta["stepping"]["path"] == "fast" and Path(meta["stepping"]["library"]).resolve().is_relative_to(site)
    assert all(Path(f["path"]).resolve().is_relative_to(site) for f in meta["fmus"]), [f["path"] for f in meta["fmus"]]
    check = subprocess.run([str(venv / "bin" / "python"), "-c",
                            "import milling_twin as mt, sys; f = mt.load_results(sys.argv[1]); "
                            "print(len(f), float(f['force.Fx'].abs().max()))", "out/slot_entry_variable"],
                           cwd=work, env=run_env, capture_output=True, text=True, timeout=120)
    assert check.returncode == 0, check.stderr[-3000:]
    rows, force = check.stdout.split()
    assert int(rows) == 1501 and float(force) > 1.0

    # a whole part: the [part] section expands against the packaged FMUs' variables
    part = _user_copy("al_bracket.toml", ("parts",), tmp_path / "user_part")
    expand = subprocess.run([command, "expand", str(part), "-o", "explicit.toml"], cwd=work, env=run_env,
                            capture_output=True, text=True, timeout=300)
    assert expand.returncode == 0, expand.stderr[-3000:]
    assert "interp, workpiece, force, vibration, power" in expand.stdout
    assert 'fmu = "CuttingForce"' in (work / "explicit.toml").read_text()
