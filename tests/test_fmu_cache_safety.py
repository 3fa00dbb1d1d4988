"""The FMU cache and loading under damaged or hostile FMUs (orchestrator.fmu_cache, orchestrator.fmu_loading):
a damaged cache entry is unzipped again, unsafe entry names and zip bombs are refused with a message naming the
FMU and the entry (no folder left), and a binary that cannot be loaded is the FMU's problem, whatever --out is."""
from __future__ import annotations

import errno
import os
import re
import shutil
import tempfile
import zipfile
from pathlib import Path

import pytest

from milling_twin.cli import main
from milling_twin.orchestrator import fmu_cache
from milling_twin.orchestrator.results import sha256_of

SCENARIO = """\
[scenario]
name = "probe"
stop_time = 0.05
output_interval = 0.01
[fmus.power]
fmu = "SpindlePower"
step_size = 0.001
[outputs]
record = ["power.P_total"]
"""


@pytest.fixture
def cache(monkeypatch, tmp_path) -> Path:
    """The cache in tmp_path/cache; temporary folders (cache off) in tmp_path/tmp."""
    monkeypatch.setenv(fmu_cache.CACHE_ENV, str(tmp_path / "cache"))
    (tmp_path / "tmp").mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path / "tmp"))
    return tmp_path / "cache"


def _binary_name(fmu: Path) -> str:
    with zipfile.ZipFile(fmu) as zf:
        return next(n for n in zf.namelist() if n.startswith("binaries/") and "SpindlePower." in n)


def _rewritten(fmu: Path, out: Path, change=lambda name, data: (name, data), extra=()) -> Path:
    """A copy of ``fmu`` with each (name, data) changed by ``change`` and ``extra`` (name, data) entries added."""
    with zipfile.ZipFile(fmu) as src, zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as dst:
        for info in src.infolist():
            name, data = change(info.filename, src.read(info))
            dst.writestr(name, data)
        for name, data in extra:
            dst.writestr(name, data)
    return out


def _damage_truncate(folder: Path, binary: str) -> None:
    path = folder / binary
    path.write_bytes(path.read_bytes()[:1000])


def _damage_modify(folder: Path, binary: str) -> None:
    path = folder / binary
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def _damage_remove(folder: Path, binary: str) -> None:
    (folder / binary).unlink()


def _damage_garbage(folder: Path, binary: str) -> None:
    (folder / binary).write_bytes(b"not a shared library")


@pytest.mark.parametrize("damage", [_damage_truncate, _damage_modify, _damage_remove, _damage_garbage])
def test_a_damaged_cache_entry_is_unzipped_again_and_runs(fmu_dir, tmp_path, cache, damage, caplog, capsys):
    fmu = fmu_dir / "SpindlePower.fmu"
    binary = _binary_name(fmu)
    with zipfile.ZipFile(fmu) as zf:
        original = zf.read(binary)
    folder = Path(fmu_cache.unpack(fmu, sha256_of(fmu)).folder)
    damage(folder, binary)
    again = fmu_cache.unpack(fmu, sha256_of(fmu))
    assert again.folder == str(folder) and (folder / binary).read_bytes() == original
    assert "damaged" in caplog.text and binary in caplog.text
    assert [p.name for p in cache.iterdir()] == [sha256_of(fmu)]  # neither the damaged copy nor a temporary one
    # and a later run works without clearing the cache by hand
    damage(folder, binary)
    scenario = tmp_path / "probe.toml"
    scenario.write_text(SCENARIO)
    code = main(["run", str(scenario), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path / "runs"), "--no-progress"])
    assert code == 0, capsys.readouterr().err


@pytest.mark.parametrize("entry, words", [
    ("/tmp/evil.txt", "an absolute path"),
    ("resources\\evil.txt", "a backslash"),
    ("C:/evil.txt", "a drive letter"),
    ("resources/../../evil.txt", "'..'"),
    ("../evil.txt", "'..'"),
])
@pytest.mark.parametrize("cached", [True, False])
def test_unsafe_entry_names_are_refused_naming_the_fmu_and_entry(fmu_dir, tmp_path, cache, monkeypatch,
                                                                  entry, words, cached):
    if not cached:
        monkeypatch.setenv(fmu_cache.CACHE_ENV, "off")
    fmu = _rewritten(fmu_dir / "SpindlePower.fmu", tmp_path / "Evil.fmu", extra=[(entry, b"x")])
    with pytest.raises(fmu_cache.FmuArchiveError) as info:
        fmu_cache.unpack(fmu, sha256_of(fmu))
    assert str(fmu) in str(info.value) and repr(entry) in str(info.value) and words in str(info.value)
    left = list(cache.iterdir()) if cache.exists() else []
    assert left == [] and list((tmp_path / "tmp").iterdir()) == []  # no folder, complete or temporary
    assert not (tmp_path / "evil.txt").exists() and not Path("/tmp/evil.txt").exists()


def test_a_zip_bomb_is_refused_and_the_limits_are_configurable(fmu_dir, tmp_path, cache, monkeypatch):
    fmu = _rewritten(fmu_dir / "SpindlePower.fmu", tmp_path / "Bomb.fmu",
                     extra=[("resources/zeros.bin", bytes(64 << 20))])
    assert fmu.stat().st_size < 1 << 20  # 64 MiB of zeros compress to about 64 kB
    with pytest.raises(fmu_cache.FmuArchiveError, match=r"entry 'resources/zeros.bin' goes beyond 100 times") as info:
        fmu_cache.unpack(fmu, sha256_of(fmu))
    assert str(fmu) in str(info.value) and fmu_cache.MAX_RATIO_ENV in str(info.value)
    assert list(cache.iterdir()) == []
    monkeypatch.setenv(fmu_cache.MAX_RATIO_ENV, "2000")
    monkeypatch.setenv(fmu_cache.MAX_BYTES_ENV, "16M")
    with pytest.raises(fmu_cache.FmuArchiveError, match=r"goes beyond 16777216 bytes") as info:
        fmu_cache.unpack(fmu, sha256_of(fmu))
    assert fmu_cache.MAX_BYTES_ENV in str(info.value) and list(cache.iterdir()) == []
    monkeypatch.setenv(fmu_cache.MAX_BYTES_ENV, "1G")
    folder = Path(fmu_cache.unpack(fmu, sha256_of(fmu)).folder)
    assert (folder / "resources" / "zeros.bin").stat().st_size == 64 << 20
    monkeypatch.setenv(fmu_cache.MAX_BYTES_ENV, "lots")
    with pytest.raises(ValueError, match=fmu_cache.MAX_BYTES_ENV):
        fmu_cache.limits()


def test_the_project_fmus_are_within_the_default_limits(fmu_dir):
    for fmu in sorted(fmu_dir.glob("*.fmu")):
        with zipfile.ZipFile(fmu) as zf:
            total = sum(i.file_size for i in zf.infolist())
        assert total < fmu_cache.MAX_BYTES and total < fmu_cache.MAX_RATIO * fmu.stat().st_size, fmu


@pytest.mark.parametrize("fmu", ["SpindlePower", "SpindlePower_fmi2"])
@pytest.mark.parametrize("out", ["relative", "absolute"])
def test_a_binary_that_cannot_be_loaded_is_the_fmus_problem(fmu_dir, tmp_path, cache, monkeypatch, capsys, out, fmu):
    bad = tmp_path / "fmus"
    bad.mkdir()
    src = fmu_dir / f"{fmu}.fmu"
    _rewritten(src, bad / f"{fmu}.fmu", change=lambda name, data: (
        name, b"not a shared library" if name == _binary_name(src) else data))
    scenario = tmp_path / "probe.toml"
    scenario.write_text(SCENARIO.replace('"SpindlePower"', '"SpindlePower"\nfmi = 2' if fmu.endswith("fmi2") else
                                         '"SpindlePower"'))
    work = tmp_path / "work"
    work.mkdir()
    monkeypatch.chdir(work)
    target = "runs" if out == "relative" else str(tmp_path / "runs")
    code = main(["run", str(scenario), "--fmu-dir", str(bad), "--out", target, "--no-progress"])
    err = capsys.readouterr().err
    assert code == 2 and os.getcwd() == str(work)  # fmpy's change of the working directory undone
    match = re.fullmatch(r"error: FMU SpindlePower \(instance power\): its binary (\S+) cannot be loaded: (.+)\n", err)
    assert match, err
    binary, reason = Path(match.group(1)), match.group(2)
    assert binary.is_file() and binary.read_bytes() == b"not a shared library" and binary.name == "SpindlePower.so"
    assert "too short" in reason and "Failed to load" not in reason and str(binary) not in reason


def test_a_damaged_entry_another_run_has_just_repaired_is_used(fmu_dir, cache, monkeypatch):
    fmu = fmu_dir / "SpindlePower.fmu"
    binary = _binary_name(fmu)
    folder = Path(fmu_cache.unpack(fmu, sha256_of(fmu)).folder)
    original = (folder / binary).read_bytes()
    _damage_garbage(folder, binary)
    real = fmu_cache.extract

    def extract_while_another_run_repairs(filename, unzipdir=None):
        done = real(filename, unzipdir=unzipdir)
        (folder / binary).write_bytes(original)  # the other run's folder, renamed into place meanwhile
        return done

    monkeypatch.setattr(fmu_cache, "extract", extract_while_another_run_repairs)
    discarded: list[Path] = []
    monkeypatch.setattr(fmu_cache, "_discard", lambda path, digest: discarded.append(path))
    assert fmu_cache.unpack(fmu, sha256_of(fmu)).folder == str(folder)
    assert discarded == [] and [p.name for p in cache.iterdir()] == [sha256_of(fmu)]


@pytest.fixture
def full_tmpfs(tmp_path):
    """A 2 MB tmpfs with 100 kB free (root only)."""
    import subprocess

    mount = tmp_path / "tmpfs"
    mount.mkdir()
    if os.geteuid() != 0 or shutil.which("mount") is None:
        pytest.skip("mounting a tmpfs needs root")
    done = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2M", "tmpfs", str(mount)], capture_output=True)
    if done.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {done.stderr.decode(errors='replace').strip()}")
    try:
        with open(mount / "filler", "wb") as fh:
            fh.write(bytes(shutil.disk_usage(mount).free - 100_000))
        yield mount
    finally:
        subprocess.run(["umount", str(mount)], check=False)


def test_unzipping_onto_a_full_disk_names_the_fmu_and_leaves_no_folder(fmu_dir, monkeypatch, full_tmpfs):
    monkeypatch.setenv(fmu_cache.CACHE_ENV, str(full_tmpfs / "cache"))
    fmu = fmu_dir / "CuttingForce.fmu"  # 1.7 MB unzipped
    with pytest.raises(OSError) as info:
        fmu_cache.unpack(fmu, sha256_of(fmu))
    assert info.value.errno == errno.ENOSPC and f"FMU {fmu}: cannot unzip " in str(info.value)
    assert str(full_tmpfs / "cache") in str(info.value.filename)
    assert list((full_tmpfs / "cache").iterdir()) == []


def test_a_folder_of_an_older_cache_without_a_file_list_is_unzipped_again_quietly(fmu_dir, cache, caplog):
    fmu = fmu_dir / "SpindlePower.fmu"
    folder = Path(fmu_cache.unpack(fmu, sha256_of(fmu)).folder)
    (folder / fmu_cache.MANIFEST).unlink()
    caplog.set_level("INFO", logger=fmu_cache.__name__)
    assert fmu_cache.unpack(fmu, sha256_of(fmu)).folder == str(folder) and (folder / fmu_cache.MANIFEST).is_file()
    assert fmu_cache.NO_RECORD in caplog.text and not [r for r in caplog.records if r.levelname == "WARNING"]
