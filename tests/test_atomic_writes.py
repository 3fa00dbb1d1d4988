"""Reports, figures and calibration outputs written atomically (orchestrator.atomic_files): a full disk or an I/O
error while one is written ends with one message naming the file, leaves no temporary file and no truncated
report.html, PNG, JSON or table: each file is complete or not there (or keeps what it had)."""
from __future__ import annotations

import builtins
import errno
import io
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path
from xml.etree import ElementTree

import pytest

from tmpfs import mounted_tmpfs

from cases.calibration_synthetic import write_power_case
from milling_twin.cli import main
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.report import write_report
from milling_twin.orchestrator.scenario import load_scenario
from milling_twin.orchestrator.study.summary import SummaryStore

PNG_END = b"IEND\xaeB`\x82"
_TEMPORARY = re.compile(r"^\.(.+?)(\.[0-9a-f]{8}|\.\d+)?\.tmp$")


def _logical(path: str | os.PathLike[str]) -> str:
    """The final name a (possibly temporary) file is written for: ``.report.html.1f2e3d4c.tmp`` -> ``report.html``."""
    name = Path(path).name
    match = _TEMPORARY.match(name)
    return match.group(1) if match else name


class _FullDisk:
    """A file that takes ``budget`` bytes and then fails with ENOSPC, like a write on a full disk."""

    def __init__(self, real: io.IOBase, budget: int) -> None:
        self._real, self._budget = real, budget

    def write(self, data):  # noqa: ANN001 - str or bytes, as the real file takes
        if len(data) > self._budget:
            self._real.write(data[:self._budget])
            self._budget = 0
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._budget -= len(data)
        return self._real.write(data)

    def __getattr__(self, name: str):
        return getattr(self._real, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc: object) -> None:
        self._real.close()

    def __iter__(self):
        return iter(self._real)


class DiskFull:
    """Files whose final name is ``target`` (under ``root``) fail after ``budget`` bytes, once ``skip`` of them
    were written whole; records what it broke."""

    def __init__(self, monkeypatch: pytest.MonkeyPatch, root: Path, target: str, budget: int = 64,
                 skip: int = 0) -> None:
        self.root, self.target, self.budget, self.skip, self.broken = str(root), target, budget, skip, []
        real = builtins.open

        def opening(file, mode="r", *args, **kwargs):  # noqa: ANN001, ANN202 - open()'s signature
            handle = real(file, mode, *args, **kwargs)
            if (isinstance(file, (str, os.PathLike)) and any(c in mode for c in "wax+")
                    and os.path.abspath(file).startswith(self.root) and _logical(file) == self.target):
                if self.skip > 0:
                    self.skip -= 1
                    return handle
                self.broken.append(Path(file))
                return _FullDisk(handle, self.budget)
            return handle

        monkeypatch.setattr(builtins, "open", opening)
        monkeypatch.setattr(io, "open", opening)


def _complete(path: Path) -> bool:
    """Whether ``path`` is a whole file of its kind (a truncated one is not)."""
    data = path.read_bytes()
    if path.suffix == ".png":
        return data.endswith(PNG_END)
    if path.suffix == ".html":
        return data.rstrip().endswith(b"</html>")
    if path.suffix == ".json":
        json.loads(data)
        return True
    if path.suffix == ".ssv":
        ElementTree.fromstring(data)
        return True
    if path.suffix == ".md":
        return b"## Figures" in data and data.endswith(b"\n")
    if path.suffix == ".stl":  # binary STL: an 80-byte header, the triangle count, 50 bytes a triangle
        return len(data) >= 84 and len(data) == 84 + 50 * int.from_bytes(data[80:84], "little")
    if path.suffix == ".csv":
        return data.endswith(b"\n") and data.count(b"\n") > 1
    return True


def _leftovers(root: Path) -> list[Path]:
    return [p for p in root.rglob("*") if p.name.startswith(".") and p.name.endswith(".tmp")]


# --- the helper itself --------------------------------------------------------------------------------------


def test_a_file_is_written_whole_with_the_usual_permissions(tmp_path):
    from milling_twin.orchestrator import atomic_files

    path = atomic_files.write_text(tmp_path / "report.html", "<html></html>\n")
    assert path.read_text() == "<html></html>\n" and os.listdir(tmp_path) == ["report.html"]
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask

    def writer(tmp: Path) -> int:
        tmp.write_text("a\n1\n")
        return 7

    assert atomic_files.write_with(tmp_path / "x.csv", writer) == 7 and (tmp_path / "x.csv").read_text() == "a\n1\n"


@pytest.mark.parametrize("failure", ["write", "short write", "fsync", "rename", "interrupt"])
def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary_one(tmp_path, monkeypatch, failure):
    from milling_twin.orchestrator import atomic_files

    path = tmp_path / "report.json"
    path.write_text('{"old": true}')
    def failing(code: int):
        def fail(*args: object) -> None:
            raise OSError(code, os.strerror(code))
        return fail

    if failure == "fsync":
        monkeypatch.setattr(atomic_files.os, "fsync", failing(errno.EIO))
    if failure == "rename":
        monkeypatch.setattr(atomic_files.os, "replace", failing(errno.EXDEV))

    def writer(tmp: Path) -> None:
        tmp.write_text('{"new": ')
        if failure == "write":
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        if failure == "short write":  # numpy's tofile (numpy-stl's binary STL) on a full disk
            raise OSError("20000 requested and 2947 written")
        if failure == "interrupt":
            raise KeyboardInterrupt

    expected = KeyboardInterrupt if failure == "interrupt" else OSError
    with pytest.raises(expected) as info:
        atomic_files.write_with(path, writer)
    if expected is OSError:
        assert info.value.filename == str(path) and str(path) in str(info.value)
        assert info.value.errno == {"write": errno.ENOSPC, "short write": errno.EIO, "fsync": errno.EIO,
                                    "rename": errno.EXDEV}[failure]
        assert "None" not in str(info.value)
    assert path.read_text() == '{"old": true}'
    assert os.listdir(tmp_path) == ["report.json"]


# --- the run's report: report.json and the comparison PNG -------------------------------------------------------


@pytest.mark.parametrize("target", ["report.json", "compare_power_P_total.png"])
def test_a_full_disk_while_the_run_report_is_written(make_case, fmu_dir, tmp_path, monkeypatch, target):
    scenario = load_scenario(make_case(), fmu_dir)
    result = run(scenario, tmp_path / "runs", progress=False)
    write_report(scenario, result.run_dir)
    before = (result.run_dir / target).read_bytes()
    full = DiskFull(monkeypatch, result.run_dir, target)
    with pytest.raises(OSError) as info:
        write_report(scenario, result.run_dir)
    monkeypatch.undo()
    assert full.broken and info.value.errno == errno.ENOSPC and info.value.filename == str(result.run_dir / target)
    assert (result.run_dir / target).read_bytes() == before  # complete, as it was
    assert _leftovers(tmp_path) == []


def test_the_run_command_names_the_file_it_could_not_write(make_case, fmu_dir, tmp_path, monkeypatch, capsys):
    out = tmp_path / "runs"
    DiskFull(monkeypatch, out, "compare_power_P_total.png")
    code = main(["run", str(make_case()), "--fmu-dir", str(fmu_dir), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err.strip()
    monkeypatch.undo()
    png = out / "case" / "compare_power_P_total.png"
    assert code == 1 and len(err.splitlines()) == 1 and "No space left on device" in err and str(png) in err
    assert not png.exists() and _leftovers(tmp_path) == []


# --- a calibration: the parameter set's SSP copy, the figures, report.md, report.html, calibration.json --------


@pytest.fixture(scope="module")
def power_case(tmp_path_factory, fmu_dir: Path) -> Path:
    return write_power_case(tmp_path_factory.mktemp("power") / "case", fmu_dir=fmu_dir, noise=5.0, seed=1)


@pytest.mark.ipopt
@pytest.mark.parametrize("target", ["power_case.params.ssv", "03.png", "report.md", "report.html",
                                    "calibration.json"])
def test_a_full_disk_at_each_calibration_output(power_case, fmu_dir, tmp_path, monkeypatch, capsys, target):
    out = tmp_path / "out"
    args = ["calibrate", str(power_case), "--fmu-dir", str(fmu_dir), "--out", str(out), "--no-progress"]
    assert main(args) == 0  # a complete calibration first: the failed one must not spoil its files
    capsys.readouterr()
    folder = out / "calibration" / "power_case"
    full = DiskFull(monkeypatch, out, target)
    code = main(args)
    err = capsys.readouterr().err.strip()
    monkeypatch.undo()
    assert full.broken, f"{target} was not written"
    final = folder / "figures" / target if target.endswith(".png") else folder / target
    assert code == 1 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert "No space left on device" in err and str(final) in err, err
    assert _leftovers(out) == []
    for path in (p for p in folder.rglob("*") if p.is_file() and "runs" not in p.relative_to(folder).parts):
        assert _complete(path), f"{path} is truncated"


def test_a_full_disk_at_the_runs_table_of_a_runs_calibration(fmu_dir, tmp_path, monkeypatch, capsys):
    from test_calibrate_runs import DATA, write_spec

    for name in ("umich_experiment_01.csv", "umich_experiment_11.csv"):
        shutil.copy(DATA / name, tmp_path / name)
    spec = write_spec(tmp_path, ["umich_experiment_01.csv", "umich_experiment_11.csv"])
    out = tmp_path / "out"
    full = DiskFull(monkeypatch, out, "runs.csv", budget=0, skip=1)  # the header written, the disk full at a row
    code = main(["calibrate", str(spec), "--fmu-dir", str(fmu_dir), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err.strip()
    monkeypatch.undo()
    table = out / "calibration" / "runs_test" / "runs.csv"
    assert full.broken and code == 1 and len(err.splitlines()) == 1, err
    assert "No space left on device" in err and str(table) in err and _leftovers(out) == []
    if table.exists():  # the rows written before the disk filled, each whole
        lines = table.read_text().splitlines()
        assert lines and len({line.count(",") for line in lines}) == 1


# --- a whole-part run's process report ---------------------------------------------------------------------


@pytest.fixture(scope="module")
def part_run(tmp_path_factory, fmu_dir: Path):
    from test_part_report import PART_EDITS, PROGRAM, TOOLS, write_part

    from milling_twin.orchestrator.results import load_results
    from milling_twin.orchestrator.scenario import with_values

    folder = tmp_path_factory.mktemp("part")
    scenario = load_scenario(write_part(folder, *PART_EDITS, program=PROGRAM, tools=TOOLS), fmu_dir)
    zmap = folder / "final.asc"
    scenario = with_values(scenario, {"workpiece.zmap_file": str(zmap)})
    result = run(scenario, folder / "runs", progress=False)
    return scenario.part, load_results(result.run_dir), zmap


@pytest.mark.parametrize("target", ["process_report.html", "process_report.json", "blocks.csv", "part.stl"])
def test_a_full_disk_while_the_process_report_is_written(part_run, tmp_path, monkeypatch, target):
    from milling_twin.orchestrator.part.report import write_process_report

    part, frame, zmap = part_run
    report_dir = tmp_path / "report"
    write_process_report(part, frame, report_dir, zmap_file=zmap)
    before = (report_dir / target).read_bytes()
    full = DiskFull(monkeypatch, report_dir, target, budget=200)
    with pytest.raises(OSError) as info:
        write_process_report(part, frame, report_dir, zmap_file=zmap)
    monkeypatch.undo()
    assert full.broken and info.value.errno == errno.ENOSPC and info.value.filename == str(report_dir / target)
    assert (report_dir / target).read_bytes() == before and _leftovers(tmp_path) == []


# --- a study's summary --------------------------------------------------------------------------------------


@pytest.mark.parametrize("target", ["study.json", "summary.csv"])
def test_a_full_disk_while_the_study_summary_is_written(tmp_path, monkeypatch, target):
    store = SummaryStore(tmp_path / "study")
    row = {"case_id": "c1", "status": "ok", "error": "", "x": 1.0, "run_status": "completed", "wall_time": 0.5,
           "run_dir": "c1"}
    store.write(row)
    store.consolidate(["c1"], ["x"])
    store.write_study({"name": "study", "cases": 1})
    before = (store.folder / target).read_bytes()
    DiskFull(monkeypatch, store.folder, target, budget=8)
    with pytest.raises(OSError) as info:
        store.write_study({"name": "study", "cases": 2}) if target == "study.json" else \
            store.consolidate(["c1"], ["x"])
    monkeypatch.undo()
    assert info.value.filename == str(store.folder / target)
    assert (store.folder / target).read_bytes() == before and _leftovers(tmp_path) == []


# --- a real full disk: a 2 MB tmpfs (root only) ---------------------------------------------------------------


def _tmpfs(tmp_path: Path, size: str):
    yield from mounted_tmpfs(tmp_path / "tmpfs", size)


@pytest.fixture
def small_tmpfs(tmp_path):
    yield from _tmpfs(tmp_path, "2M")


@pytest.fixture
def tmpfs_16m(tmp_path):
    yield from _tmpfs(tmp_path, "16M")


def _fill(mount: Path, leave: int) -> None:
    with open(mount / "filler", "wb") as fh:
        fh.write(bytes(shutil.disk_usage(mount).free - leave))


@pytest.mark.ipopt
def test_a_calibration_onto_a_full_tmpfs_fails_cleanly(power_case, fmu_dir, small_tmpfs):
    """The calibration's outputs take about 1.5 MB; the tmpfs is filled up to leave 300 kB."""
    _fill(small_tmpfs, 300_000)
    done = subprocess.run([sys.executable, "-m", "milling_twin", "calibrate", str(power_case), "--fmu-dir",
                           str(fmu_dir), "--out", str(small_tmpfs / "out"), "--no-progress"],
                          capture_output=True, text=True, timeout=600)
    err = done.stderr.strip()
    assert done.returncode == 1 and "Traceback" not in err, err
    last = err.splitlines()[-1]
    assert last.startswith("error: ") and "No space left on device" in last and str(small_tmpfs) in last, err
    assert _leftovers(small_tmpfs) == []
    folder = small_tmpfs / "out" / "calibration" / "power_case"
    for path in (p for p in folder.rglob("*") if p.is_file() and "runs" not in p.relative_to(folder).parts):
        assert _complete(path), f"{path} is truncated"


def test_a_whole_part_run_onto_a_full_tmpfs_fails_cleanly(fmu_dir, tmp_path, tmpfs_16m):
    """The run's results fit, its process report (HTML 0.5 MB, STL 0.6 MB) does not."""
    from test_part_report import PART_EDITS, PROGRAM, TOOLS, write_part

    scenario = write_part(tmp_path / "part", *PART_EDITS, program=PROGRAM, tools=TOOLS)

    def run_into(out: Path) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "milling_twin", "run", str(scenario), "--fmu-dir", str(fmu_dir),
                               "--out", str(out), "--no-progress"], capture_output=True, text=True, timeout=600)

    assert run_into(tmp_path / "complete").returncode == 0
    folder = next((tmp_path / "complete").iterdir())
    sizes = {p.name: p.stat().st_size for p in folder.rglob("*") if p.is_file()}
    _fill(tmpfs_16m, sum(sizes.values()) - sizes["part.stl"] // 2 - sizes["process_report.html"])
    done = run_into(tmpfs_16m / "out")
    err = done.stderr.strip()
    assert done.returncode == 1 and "Traceback" not in err, err
    last = err.splitlines()[-1]
    assert last.startswith("error: ") and str(tmpfs_16m / "out" / folder.name) in last, err
    assert re.search(r"\[Errno \d+\] [^:]+: '[^']+/(part\.stl|process_report\.html|final_zmap\.asc)'", last), last
    assert _leftovers(tmpfs_16m) == []
    for path in (p for p in (tmpfs_16m / "out").rglob("*") if p.is_file()):
        assert _complete(path), f"{path} is truncated"
