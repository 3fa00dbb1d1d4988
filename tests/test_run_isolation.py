"""Runs that cannot mix or escape their folder (issue 22, items 1, 2, 4, the run side of 5 and SIGTERM/SIGHUP of
8): the run folder's lock and ``--if-busy``, run ids in chunks and ``run.json``, names that must be one path
component, the parameter set written by tomli-w, signals and a full disk while a run writes."""
from __future__ import annotations

import errno
import json
import os
import signal
import subprocess
import sys
import time
import tomllib
from dataclasses import replace
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from tmpfs import mounted_tmpfs

from cases.calibration_synthetic import write_power_case
from conftest import LONG_TOML, REPO_ROOT, running_long
from milling_twin import api
from milling_twin.cli import main
from milling_twin.orchestrator.calibrate import CalibrationSpecError, load_spec
from milling_twin.orchestrator.master import run
from milling_twin.orchestrator.results import (MixedRunError, ResultsWriteError, RunFolder, RunFolderBusy,
                                               RunWriter, load_results, read_run_info)
from milling_twin.orchestrator.safe_names import name_problem
from milling_twin.orchestrator.scenario import ScenarioError, load_scenario, with_values
from milling_twin.orchestrator.study.spec import StudyError, load_study

SHORT_LONG = LONG_TOML.replace("stop_time = 100000.0", "stop_time = 0.5")  # same name "long", 51 rows


def _hidden(folder: Path) -> list[Path]:
    """Temporary and lock files left in a run folder (every such name starts with a dot)."""
    return [p for p in folder.rglob("*") if p.name.startswith(".")]


def _cli(*args: str, cwd: Path = REPO_ROOT) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "milling_twin", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=300)


def _chunk_ids(run_dir: Path) -> set[str]:
    return {pq.read_schema(p).metadata[b"run_id"].decode() for p in (run_dir / "chunks").glob("chunk_*.parquet")}


# ---- item 1: two runs into one folder ----


def test_a_second_run_into_a_busy_folder_refuses_and_leaves_the_first_alone(long_run, tmp_path: Path,
                                                                          fmu_dir: Path) -> None:
    proc, run_dir = long_run
    second = tmp_path / "second.toml"
    second.write_text(SHORT_LONG)
    done = _cli("run", str(second), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path / "runs"), "--no-progress")
    assert done.returncode == 1, done.stdout + done.stderr  # (it ran into the first run's folder: exit 0)
    first_id = read_run_info(run_dir)["run_id"]
    assert done.stderr.startswith(f"error: {run_dir} is the folder of a run in progress (process {proc.pid} "
                                  f"(run {first_id}, since "), done.stderr
    assert "--if-busy wait" in done.stderr and "Traceback" not in done.stderr
    assert proc.poll() is None
    proc.send_signal(signal.SIGINT)
    proc.communicate(timeout=60)
    info = read_run_info(run_dir)
    assert info["run_id"] == first_id and info["status"] == "interrupted"
    assert _chunk_ids(run_dir) == {first_id}
    assert len(load_results(run_dir)) == info["rows_written"]
    assert not _hidden(run_dir)  # the lock file went with the lock


def test_if_busy_new_takes_a_suffixed_folder(long_run, tmp_path: Path, fmu_dir: Path) -> None:
    proc, run_dir = long_run
    second = tmp_path / "second.toml"
    second.write_text(SHORT_LONG)
    done = _cli("run", str(second), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path / "runs"), "--no-progress",
                "--if-busy", "new")
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"results: {tmp_path / 'runs' / 'long-2'} " in done.stdout
    other = tmp_path / "runs" / "long-2"
    assert read_run_info(other)["status"] == "completed" and len(load_results(other)) == 51
    assert read_run_info(run_dir)["status"] == "running" and proc.poll() is None
    assert read_run_info(other)["run_id"] != read_run_info(run_dir)["run_id"]


def test_if_busy_wait_starts_when_the_first_run_ends(long_run, tmp_path: Path, fmu_dir: Path) -> None:
    proc, run_dir = long_run
    first_id = read_run_info(run_dir)["run_id"]
    second = tmp_path / "second.toml"
    second.write_text(SHORT_LONG)
    waiting = subprocess.Popen(
        [sys.executable, "-m", "milling_twin", "run", str(second), "--fmu-dir", str(fmu_dir), "--out",
         str(tmp_path / "runs"), "--no-progress", "--if-busy", "wait"],
        cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(3.0)
        assert waiting.poll() is None  # still waiting
        assert read_run_info(run_dir)["run_id"] == first_id  # nothing of its own written yet
        proc.send_signal(signal.SIGINT)
        proc.communicate(timeout=60)
        out, err = waiting.communicate(timeout=120)
    finally:
        if waiting.poll() is None:
            waiting.kill()
    assert waiting.returncode == 0, out + err
    info = read_run_info(run_dir)
    assert info["status"] == "completed" and info["run_id"] != first_id
    assert _chunk_ids(run_dir) == {info["run_id"]} and len(load_results(run_dir)) == 51


def test_claiming_a_folder_in_one_process_twice(tmp_path: Path) -> None:
    with RunFolder.claim(tmp_path / "r") as first:
        with pytest.raises(RunFolderBusy, match=r"r is the folder of a run in progress \(process \d+ \(run "):
            RunFolder.claim(tmp_path / "r")
        with RunFolder.claim(tmp_path / "r", "new") as other:
            assert other.path == tmp_path / "r-2" and other.run_id != first.run_id
    with RunFolder.claim(tmp_path / "r", "wait") as again:  # free again
        assert again.path == tmp_path / "r"
    assert not _hidden(tmp_path)
    with pytest.raises(ValueError, match="if_busy='later': expected one of refuse, wait, new"):
        RunFolder.claim(tmp_path / "r", "later")


def test_every_chunk_and_run_json_carry_the_run_id(tmp_path: Path) -> None:
    writer = RunWriter(tmp_path / "r", ["time", "a.x"], flush_rows=2, flush_seconds=3600)
    for i in range(5):
        writer.append([i, 2.0 * i])
    writer.finish("completed")
    info = read_run_info(tmp_path / "r")
    assert len(info["run_id"]) == 32 and _chunk_ids(tmp_path / "r") == {info["run_id"]}
    assert len(load_results(tmp_path / "r")) == 5


def test_load_results_refuses_chunks_of_another_run(tmp_path: Path) -> None:
    for name, offset in (("a", 0.0), ("b", 100.0)):
        writer = RunWriter(tmp_path / name, ["time", "x"], flush_rows=2, flush_seconds=3600)
        for i in range(4):
            writer.append([offset + i, i])
        writer.finish("completed")
    stray = tmp_path / "a" / "chunks" / "chunk_000003.parquet"
    os.replace(tmp_path / "b" / "chunks" / "chunk_000002.parquet", stray)
    with pytest.raises(MixedRunError, match=rf"^{stray}: written by run [0-9a-f]{{32}}, not by run [0-9a-f]{{32}} "
                                            rf"of {tmp_path / 'a' / 'run.json'}: .* mixes the results of two runs"):
        load_results(tmp_path / "a")
    (tmp_path / "a" / "run.json").unlink()  # without run.json: the first chunk's run
    with pytest.raises(MixedRunError, match=f"^{stray}: written by run "):
        load_results(tmp_path / "a")


# ---- item 2: names that must stay one path component ----


@pytest.mark.parametrize("name", ["..", ".", "...", "con", "a."])
def test_name_problems(name: str) -> None:
    assert name_problem(name) is not None
    assert name_problem("spindle_depth-2.v1") is None


def test_a_scenario_named_dotdot_cannot_leave_the_output_folder(make_case, fmu_dir: Path, tmp_path: Path,
                                                                capsys) -> None:
    user_file = tmp_path / "chunks" / "mine.txt"  # <out>/../chunks/ of the finding
    user_file.parent.mkdir()
    user_file.write_text("keep me")
    (tmp_path / "report.json").write_text("keep me too")
    path = make_case(('name = "case"', 'name = ".."'))
    code = main(["run", str(path), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path / "out"), "--no-progress"])
    assert code == 2
    assert capsys.readouterr().err == (f"error: {path}: [scenario].name: '..' is made of dots only ('.' and '..' "
                                       "name a folder outside the output folder): it names the run's folder "
                                       "<out>/<name>/\n")
    assert user_file.read_text() == "keep me" and (tmp_path / "report.json").read_text() == "keep me too"
    assert not (tmp_path / "run.json").exists()


def test_with_values_and_run_refuse_a_dotdot_name(make_case, fmu_dir: Path, tmp_path: Path) -> None:
    scenario = load_scenario(make_case(), fmu_dir)
    with pytest.raises(ScenarioError, match=r"with_values\(name\): '\.\.' is made of dots only"):
        with_values(scenario, {}, name="..")
    with pytest.raises(ValueError, match=r"\[scenario\].name: '\.' is made of dots only"):
        run(replace(scenario, name="."), tmp_path / "out", progress=False)
    with pytest.raises(ValueError, match=r"\[scenario\].name: '\.\.' is made of dots only"):
        api.simulate(replace(scenario, name=".."), out=tmp_path / "out")
    assert not (tmp_path / "chunks").exists() and not (tmp_path / "run.json").exists()


def test_a_calibration_spec_named_dotdot_is_refused(tmp_path: Path) -> None:
    spec = write_power_case(tmp_path / "case")
    spec.write_text(spec.read_text().replace('name = "power_case"', 'name = ".."'))
    with pytest.raises(CalibrationSpecError, match=r"power_case_spec.toml: \[calibration\].name: '\.\.' is made of "
                                                   r"dots only .*<out>/calibration/<name>/"):
        load_spec(spec)


def test_a_study_named_dotdot_is_refused(tmp_path: Path, fmu_dir: Path) -> None:
    path = tmp_path / "study.toml"
    path.write_text(f'[study]\nname = ".."\nbase = "{(REPO_ROOT / "scenarios" / "chatter.toml").as_posix()}"\n')
    with pytest.raises(StudyError, match=r"study.toml: study.name: '\.\.' is made of dots only"):
        load_study(path, fmu_dir)


@pytest.mark.ipopt
def test_a_spec_parameter_set_elsewhere_is_written_only_under_out(tmp_path: Path, fmu_dir: Path) -> None:
    """The spec's parameter_set names the committed file; a calibration writes its file name under --out and
    publishes to a path only when --write-set gives it."""
    spec = write_power_case(tmp_path / "case", fmu_dir=fmu_dir)
    target = tmp_path / "elsewhere" / "victim.toml"
    target.parent.mkdir()
    target.write_text("# the user's file\n")
    spec.write_text(spec.read_text().replace('parameter_set = "power_case.params.toml"',
                                             f'parameter_set = "{target.as_posix()}"'))
    out = tmp_path / "out"
    assert main(["calibrate", str(spec), "--fmu-dir", str(fmu_dir), "--out", str(out), "--no-progress"]) == 0
    assert target.read_text() == "# the user's file\n"
    assert tomllib.loads((out / "calibration" / "power_case" / "victim.toml").read_text())["parameters"]["power"]


# ---- item 4: a multi-line description ----


@pytest.mark.ipopt
def test_a_multi_line_description_round_trips_through_the_calibration(tmp_path: Path, fmu_dir: Path) -> None:
    spec = write_power_case(tmp_path / "case", fmu_dir=fmu_dir)
    description = 'Line one,\nline "two" with a \\ backslash\n\tand a tab = [x]'
    spec.write_text(spec.read_text().replace('description = "synthetic power case"',
                                             f"description = {json.dumps(description)}"))
    out = tmp_path / "out"
    assert main(["calibrate", str(spec), "--fmu-dir", str(fmu_dir), "--out", str(out), "--no-progress"]) == 0
    folder = out / "calibration" / "power_case"
    written = tomllib.loads((folder / "power_case.params.toml").read_text())
    assert written["description"] == description
    assert set(written["parameters"]["power"]) == {"P_standby", "P_idle", "c1", "c2", "c3"}
    assert (folder / "report.html").is_file()
    assert not _hidden(folder)


# ---- SIGTERM and SIGHUP ----


@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_sigterm_and_sighup_end_a_run_like_ctrl_c(long_run, signum: int) -> None:
    proc, run_dir = long_run
    proc.send_signal(signum)
    out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, out + err
    info = read_run_info(run_dir)
    assert info["status"] == "interrupted" and info["signal"] == signal.Signals(signum).name
    frame = load_results(run_dir)
    assert len(frame) == info["rows_written"] > 0
    # the buffered rows were flushed: the last row is the last output point the run reached
    assert info["end_time"] - 0.01 - 1e-9 <= frame["time"].iloc[-1] <= info["end_time"] + 1e-9
    assert out.startswith("interrupted: ")
    assert not _hidden(run_dir)


def test_a_signal_ignored_at_start_stays_ignored(tmp_path: Path, fmu_dir: Path) -> None:
    """Under nohup SIGHUP is ignored: the run goes on through it, and still stops on SIGINT."""
    with running_long(tmp_path, fmu_dir, ignored=(signal.SIGHUP,)) as (proc, run_dir):
        proc.send_signal(signal.SIGHUP)
        time.sleep(0.3)
        assert proc.poll() is None, proc.communicate()
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, out + err
    assert read_run_info(run_dir)["signal"] == "SIGINT"


# ---- the run side of item 5: a full disk ----


def _full_disk_after(monkeypatch, chunks: int) -> None:
    """pyarrow's write_table writes half a chunk, then the disk is full, from the ``chunks + 1``-th chunk on."""
    import pyarrow.parquet as parquet

    real = parquet.write_table
    calls = {"n": 0}

    def write_table(table, where, **kwargs):
        calls["n"] += 1
        if calls["n"] <= chunks:
            return real(table, where, **kwargs)
        where.write(b"PAR1" * 64)
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(parquet, "write_table", write_table)


@pytest.mark.parametrize("stepping", ["python", "fast"])
def test_a_full_disk_ends_the_run_with_one_message_and_run_json_saying_so(monkeypatch, tmp_path: Path,
                                                                         fmu_dir: Path, stepping: str) -> None:
    scenario_path = tmp_path / "long.toml"
    scenario_path.write_text(LONG_TOML.replace("stop_time = 100000.0", "stop_time = 100.0"))
    scenario = load_scenario(scenario_path, fmu_dir)
    _full_disk_after(monkeypatch, 2)
    with pytest.raises(ResultsWriteError) as caught:
        run(scenario, tmp_path / "out", progress=False, flush_rows=1000, stepping=stepping)
    run_dir = tmp_path / "out" / "long"
    chunk = run_dir / "chunks" / "chunk_000003.parquet"
    assert str(caught.value) == f"cannot write {chunk}: No space left on device"
    assert caught.value.errno == errno.ENOSPC
    info = read_run_info(run_dir)
    assert info["status"] == f"failed: cannot write {chunk}: No space left on device"
    assert info["rows_written"] == 2000 and len(load_results(run_dir)) == 2000
    assert not _hidden(run_dir)  # no temporary chunk, no lock file


def test_a_full_disk_through_the_cli_is_one_line(monkeypatch, tmp_path: Path, fmu_dir: Path, capsys) -> None:
    scenario_path = tmp_path / "long.toml"
    scenario_path.write_text(LONG_TOML.replace("stop_time = 100000.0", "stop_time = 30.0"))
    _full_disk_after(monkeypatch, 0)  # the run is shorter than a flush: its one chunk is written at the end
    code = main(["run", str(scenario_path), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path / "out"),
                 "--no-progress", "--path", "python"])
    run_dir = tmp_path / "out" / "long"
    chunk = run_dir / "chunks" / "chunk_000001.parquet"
    assert code == 1
    assert capsys.readouterr().err == (f"error: cannot write the results to {run_dir}: cannot write {chunk}: "
                                       "No space left on device\n")
    assert read_run_info(run_dir)["status"].startswith(f"failed: cannot write {chunk}")
    assert not _hidden(run_dir)


def test_run_json_is_rewritten_in_place_when_there_is_no_room_for_a_copy(monkeypatch, tmp_path: Path) -> None:
    """The final run.json: when its temporary copy cannot be written for want of space, the old one is
    rewritten in place, so that it does not keep saying "running"."""
    import milling_twin.orchestrator.results as results

    writer = RunWriter(tmp_path / "r", ["time"], flush_rows=10, flush_seconds=3600)
    writer.append([0.0])
    real = results._replace_atomically

    def no_room(path, write, durable=False):
        if path.name == "run.json":
            raise results.ResultsWriteError(f"cannot write {path}: No space left on device")
        return real(path, write, durable)

    def no_room_with_errno(path, write, durable=False):
        try:
            no_room(path, write, durable)
        except results.ResultsWriteError as exc:
            exc.errno = errno.ENOSPC
            raise

    monkeypatch.setattr(results, "_replace_atomically", no_room_with_errno)
    writer.finish("completed")
    info = read_run_info(tmp_path / "r")
    assert info["status"] == "completed" and info["rows_written"] == 1
    assert not _hidden(tmp_path / "r")


@pytest.fixture
def tiny_disk(tmp_path: Path):
    """A 1 MiB tmpfs (root only; skipped where it cannot be mounted), unmounted at teardown."""
    yield from mounted_tmpfs(tmp_path / "disk", "1M")


@pytest.mark.parametrize("stepping", ["python", "fast"])
def test_a_really_full_disk(tiny_disk: Path, tmp_path: Path, fmu_dir: Path, stepping: str) -> None:
    """A run of 200,000 rows of 4 columns (about 1 MB of Parquet) into 1 MiB: the 20th chunk does not fit."""
    scenario = tmp_path / "long.toml"
    scenario.write_text(LONG_TOML.replace("stop_time = 100000.0", "stop_time = 200.0")
                        .replace("output_interval = 0.01", "output_interval = 0.001")
                        .replace('"power.spindle_on"]', '"power.spindle_on", "power.P_cutting"]'))
    done = _cli("run", str(scenario), "--fmu-dir", str(fmu_dir), "--out", str(tiny_disk / "runs"), "--no-progress",
                "--path", stepping)
    run_dir = tiny_disk / "runs" / "long"
    assert done.returncode == 1, done.stdout + done.stderr
    lines = done.stderr.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"error: cannot write the results to {run_dir}: cannot write "
                                                   f"{run_dir / 'chunks'}/chunk_"), done.stderr
    assert lines[0].endswith(".parquet: No space left on device")
    info = read_run_info(run_dir)
    assert info["status"] == "failed: " + lines[0].split(f"{run_dir}: ", 1)[1]
    assert 0 < info["rows_written"] == len(load_results(run_dir)) < 200_001
    assert not _hidden(run_dir)


def test_sigterm_stops_a_serial_study_after_the_case_it_interrupts(tmp_path: Path, fmu_dir: Path) -> None:
    """In a study run in this process (--workers 0), SIGTERM interrupts the case's run (its rows are kept) and
    stops the study, as it stopped the process before: it does not go on to the next case."""
    base = tmp_path / "long.toml"
    base.write_text(LONG_TOML)
    study = tmp_path / "study.toml"
    study.write_text(f'[study]\nname = "s"\nbase = "{base.as_posix()}"\n'
                     '[study.grid]\n"power.P_idle" = [200.0, 300.0]\n'
                     '[[study.reduce]]\nkind = "max"\nvariable = "power.P_total"\n')
    proc = subprocess.Popen([sys.executable, "-m", "milling_twin", "sweep", str(study), "--fmu-dir", str(fmu_dir),
                             "--out", str(tmp_path / "runs"), "--workers", "0", "--no-progress"],
                            cwd=REPO_ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not list((tmp_path / "runs" / "s" / "cases").glob("*/chunks/chunk_*.parquet")):
            assert proc.poll() is None and time.monotonic() < deadline, proc.communicate()
            time.sleep(0.05)
        proc.send_signal(signal.SIGTERM)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 130, out + err
    assert err.startswith("interrupted; the finished cases are kept in ") and "--resume runs the others" in err
    cases = list((tmp_path / "runs" / "s" / "cases").iterdir())
    assert len(cases) == 1  # the second case never started
    info = read_run_info(cases[0])
    assert info["status"] == "interrupted" and info["signal"] == "SIGTERM"


def test_a_study_or_calibration_folder_in_use_is_refused(tmp_path: Path, fmu_dir: Path, capsys) -> None:
    """A sweep or a calibration owns its folder like a run (two at once would mix their summaries, reports and
    parameter sets); the case and re-simulation folders inside are claimed by their runs."""
    study = tmp_path / "study.toml"
    base = tmp_path / "long.toml"
    base.write_text(SHORT_LONG)
    study.write_text(f'[study]\nname = "s"\nbase = "{base.as_posix()}"\n[study.grid]\n"power.P_idle" = [200.0]\n'
                     '[[study.reduce]]\nkind = "max"\nvariable = "power.P_total"\n')
    spec = write_power_case(tmp_path / "case", fmu_dir=fmu_dir)
    out = tmp_path / "out"
    with RunFolder.claim(out / "s", what="study"), RunFolder.claim(out / "calibration" / "power_case"):
        assert main(["sweep", str(study), "--fmu-dir", str(fmu_dir), "--out", str(out), "--workers", "0",
                     "--no-progress"]) == 1
        assert capsys.readouterr().err.startswith(
            f"error: {out / 's'} is the folder of a study in progress (process {os.getpid()} (run ")
        assert main(["calibrate", str(spec), "--fmu-dir", str(fmu_dir), "--out", str(out), "--no-progress"]) == 1
        err = capsys.readouterr().err
        assert err.startswith(f"error: {out / 'calibration' / 'power_case'} is the folder of a calibration in "
                              f"progress (process {os.getpid()} (run ") and err.endswith(
            "its files would mix with this calibration's; wait for it or choose another output folder (--out)\n")
    assert main(["sweep", str(study), "--fmu-dir", str(fmu_dir), "--out", str(out), "--workers", "0",
                 "--no-progress"]) == 0
    assert not _hidden(out)


def test_an_ssp_archive_named_dotdot_is_refused(make_case, fmu_dir: Path, tmp_path: Path, capsys) -> None:
    """An SSP archive's SystemStructureDescription name becomes the run's folder too."""
    import zipfile

    archive = tmp_path / "case.ssp"
    assert main(["export-ssp", str(make_case()), "-o", str(archive), "--fmu-dir", str(fmu_dir)]) == 0
    capsys.readouterr()
    bad = tmp_path / "bad.ssp"
    with zipfile.ZipFile(archive) as src, zipfile.ZipFile(bad, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "SystemStructure.ssd":
                data = data.replace(b'name="case"', b'name=".."', 1)
                assert b'name=".."' in data
            dst.writestr(item, data)
    code = main(["run", str(bad), "--out", str(tmp_path / "out"), "--no-progress"])
    assert code == 2
    assert capsys.readouterr().err == (
        f"error: {bad}: SystemStructure.ssd: <ssd:SystemStructureDescription name='..'>: '..' is made of dots only "
        "('.' and '..' name a folder outside the output folder): it names the run's folder <out>/<name>/\n")
    assert not (tmp_path / "run.json").exists() and not (tmp_path / "chunks").exists()
