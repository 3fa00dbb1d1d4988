"""Files a user names are untrusted input (orchestrator/input_files.py, orchestrator/gcode/recognise.py,
orchestrator/recorded.py, orchestrator/toml_access.py): only regular files are opened, and never block; a file that
is not of the kind asked for is refused without quoting it, so nothing of it reaches a message or run.json; TOML
nesting and the cost of a channel's regular expression are bounded; a byte that is not UTF-8 is named by its line
and column; a recording is read only as far as the run goes."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from conftest import CASE_CSV, REPO_ROOT
from milling_twin.cli import main
from milling_twin.orchestrator.recorded import ChannelSpec, RecordedDataError, load_recorded
from milling_twin.orchestrator.scenario import ScenarioError, load_scenario

SECRET = "untrusted-7f3a9c"
INTERP_TOML = """\
[scenario]
name = "untrusted"
stop_time = 0.05
output_interval = 0.01
[fmus.interp]
fmu = "Interpolator"
step_size = 0.001
[fmus.interp.parameters]
program = {program}
[outputs]
record = ["interp.x"]
"""
STOP_AT_02 = ("output_interval = 0.1", "output_interval = 0.1\nstop_time = 0.2")


def error_of(path: Path, fmu_dir: Path) -> str:
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    return str(info.value)


def interp_case(tmp_path: Path, program: str) -> Path:
    path = tmp_path / "untrusted.toml"
    path.write_text(INTERP_TOML.format(program=program))
    return path


def part_case(tmp_path: Path, program: str) -> Path:
    """scenarios/al_plate.toml (a whole-part scenario) with another ``program``, in tmp_path."""
    text = (REPO_ROOT / "scenarios" / "al_plate.toml").read_text()
    tools = (REPO_ROOT / "scenarios" / "parts" / "plate_tools.tbl").resolve()
    text = text.replace('"parts/al_plate.nc"', json.dumps(program)).replace('"parts/plate_tools.tbl"',
                                                                             json.dumps(str(tools)))
    path = tmp_path / "part.toml"
    path.write_text(text)
    return path


def fifo(tmp_path: Path, name: str) -> Path:
    if not hasattr(os, "mkfifo"):
        pytest.skip("no FIFOs on this platform")
    path = tmp_path / name
    os.mkfifo(path)
    return path


# ---- only regular files ----


def test_a_program_under_proc_is_refused_without_its_content(tmp_path: Path, fmu_dir: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SECRET_TOKEN", SECRET)
    for path, key in ((interp_case(tmp_path, '{ path = "/proc/self/environ" }'),
                       "[fmus.interp].parameters.program.path"),
                      (part_case(tmp_path, "/proc/self/environ"), "[part].program")):
        message = error_of(path, fmu_dir)
        assert f"{path}: {key}: /proc/" in message and "is under /proc, a kernel interface, not a regular file " \
               "(the part program must be one)" in message, message
        assert SECRET not in message


@pytest.mark.parametrize("where", ["scenario file", "program", "tool table", "recording", "parameter set"])
def test_a_fifo_is_refused_at_once(tmp_path: Path, fmu_dir: Path, make_case, where: str) -> None:
    """In a child process with a time limit: a reader that opened a FIFO would wait for a writer for ever."""
    pipe = fifo(tmp_path, "pipe")
    path, key = {
        "scenario file": lambda: (pipe, ""),
        "program": lambda: (interp_case(tmp_path, json.dumps(str(pipe))), "[fmus.interp].parameters.program: "),
        "tool table": lambda: (interp_case(tmp_path, '"prog.nc"\ntool_table = { path = "pipe" }'),
                               "[fmus.interp].parameters.tool_table.path: "),
        "recording": lambda: (make_case(('file = "data.csv"', 'file = "pipe"')), "[recorded].file: "),
        "parameter set": lambda: (make_case(("output_interval = 0.1",
                                             'output_interval = 0.1\nparameter_sets = ["pipe"]')),
                                  "[scenario].parameter_sets[0]: "),
    }[where]()
    (tmp_path / "prog.nc").write_text("G21 G90\nM30\n")
    code = textwrap.dedent(f"""
        from milling_twin.orchestrator.scenario import ScenarioError, load_scenario
        try:
            load_scenario({str(path)!r}, {str(fmu_dir)!r})
        except ScenarioError as exc:
            print(exc)
        """)
    try:
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail(f"the {where} as a FIFO blocked the reader")
    assert f"{path}: {key}" in proc.stdout and "is a FIFO (named pipe), not a regular file" in proc.stdout, \
        proc.stdout + proc.stderr


def test_special_files_as_recordings_are_refused_without_their_content(make_case, fmu_dir: Path,
                                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("SECRET_TOKEN", SECRET)
    for file, what in (("/proc/self/environ", "is under /proc, a kernel interface, not a regular file"),
                       ("/dev/zero", "is a device, not a regular file"), (".", "is a directory, not a regular file")):
        message = error_of(make_case(('file = "data.csv"', f'file = "{file}"')), fmu_dir)
        assert "[recorded].file: " in message and what in message, message
        assert SECRET not in message


# ---- files of another kind: refused without their content ----


def test_a_file_that_is_not_a_program_is_refused_and_nothing_of_it_reaches_run_json(
        tmp_path: Path, fmu_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    notes = tmp_path / "notes.txt"
    notes.write_text(f"SECRET_TOKEN={SECRET}\nroot:x:0:0:root:/root:/bin/bash\n")
    out = tmp_path / "out"
    for path, key in ((interp_case(tmp_path, '{ path = "notes.txt" }'), "[fmus.interp].parameters.program.path"),
                      (part_case(tmp_path, str(notes)), "[part].program")):
        code = main(["run", str(path), "--fmu-dir", str(fmu_dir), "--out", str(out), "--no-progress"])
        err = capsys.readouterr().err
        assert code == 2 and f"{key}: {notes}: not a part program (line 1, its first line with content, does not " \
                             "start with a G-code word such as G1, N10, T1 or O1000)" in err, err
        assert SECRET not in err
        written = [p for p in out.rglob("*") if p.is_file()] if out.exists() else []
        assert not any(SECRET in p.read_text(errors="replace") for p in written), written


def test_a_text_file_that_is_not_csv_is_refused_without_its_content(make_case, fmu_dir: Path) -> None:
    path = make_case(csv=f"root:x:0:0:{SECRET}:/root:/bin/bash\ndaemon:x:1:1::/usr/sbin\n")
    message = error_of(path, fmu_dir)
    assert message.endswith("[recorded].file: <dir>/data.csv: not a CSV recording (line 1 is not a header of "
                            "comma-separated column names; looked for the column 'speed')".replace(
                                "<dir>", str(path.parent))), message
    assert SECRET not in message and "root:x" not in message


# ---- TOML nesting, regular expressions, decoding ----


def test_toml_nested_2000_levels_is_a_clear_error(make_case, fmu_dir: Path) -> None:
    path = make_case(("output_interval = 0.1", "output_interval = 0.1\nx = " + "[" * 2000 + "]" * 2000))
    assert error_of(path, fmu_dir) == f"{path}: line 4, column 37: arrays and inline tables nested more than 32 levels"
    path = make_case(("output_interval = 0.1", "output_interval = 0.1\n" + ".".join(["a"] * 3000) + " = 1"))
    assert error_of(path, fmu_dir) == (f"{path}: scenario.a.a.a...: tables, dotted keys and arrays nested more than 32 "
                                       f"levels")


@pytest.mark.parametrize("pattern, why", [
    ("(a+)+$", "a repeat inside a repeat (like (a+)+) can take exponential time"),
    ("(a|aa)*b", "an alternation inside a repeat (like (a|ab)*) can take exponential time"),
    ("(a)\\\\1", "a backreference"),
    ("a.*b.*c.*d", "3 unbounded repeats (*, +, {n,}), more than 2"),
], ids=["nested repeats", "alternation in a repeat", "backreference", "three unbounded repeats"])
def test_a_catastrophic_match_pattern_is_refused(make_case, fmu_dir: Path, pattern: str, why: str) -> None:
    path = make_case(('match = "^Layer"', f'match = "{pattern}"'), csv=CASE_CSV.replace("Prep", "a" * 24 + "!"))
    message = error_of(path, fmu_dir)
    assert message.startswith(f"{path}: [recorded.channels].cutting: ") and why in message, message


def test_a_match_reads_labels_of_at_most_1000_characters(make_case, fmu_dir: Path) -> None:
    assert load_scenario(make_case(), fmu_dir).recorded.channels["cutting"].tolist() == [False, True, True, False,
                                                                                         False]
    path = make_case(csv=CASE_CSV.replace("Prep", "P" * 1001))
    assert error_of(path, fmu_dir).endswith("data.csv, line 2, column 'process': a cell of 1001 characters, more than "
                                            "the 1000 a 'match' channel reads (channel 'cutting')")


def test_a_non_utf8_byte_is_named_by_line_and_column(make_case, fmu_dir: Path, tmp_path: Path) -> None:
    path = make_case()
    path.write_bytes(path.read_bytes().replace(b'name = "case"', b'name = "ca\xffse"'))
    assert error_of(path, fmu_dir) == (f"{path}: line 2, column 11: byte 0xff is not valid UTF-8: the scenario file "
                                       f"must be UTF-8 text")
    rows = "".join(f"{i % 7},3,4,Layer 1 Up,0.38\n" for i in range(5000))
    data = tmp_path / "long.csv"
    data.write_bytes(("speed,vx,vy,process,power\n" + rows).encode() + b"1,3,4,La\xe9yer,0.38\n")
    with pytest.raises(RecordedDataError) as info:
        load_recorded(data, [ChannelSpec("cutting", "process", "bool", match="^Layer")], sample_period=0.1)
    assert str(info.value) == (f"{data}, line 5002, column 9: byte 0xe9 is not valid UTF-8: a recording must be "
                               f"UTF-8 text")


# ---- a recording is read as far as the run goes ----


def test_a_recording_is_read_only_as_far_as_the_run_goes(make_case, fmu_dir: Path) -> None:
    broken = CASE_CSV + "0,0\n"  # a truncated row after the run's end
    scenario = load_scenario(make_case(STOP_AT_02, csv=broken), fmu_dir)
    assert scenario.recorded.time.tolist() == [0.0, 0.1, 0.2]
    message = error_of(make_case(csv=CASE_CSV + "0,0\n"), fmu_dir)  # without stop_time the whole file is read
    assert message.endswith("data.csv, line 7: truncated line: 2 fields, but the header (line 1) has 5 fields")


def test_the_memory_of_a_long_recording_is_bounded_by_the_run(make_case, fmu_dir: Path, tmp_path: Path) -> None:
    """A 70 MB recording of which a run ending at 0.2 s reads 3 rows: the peak memory grows by less than 30 MB."""
    path = make_case(STOP_AT_02, csv="speed,vx,vy,process,power\n")
    with (tmp_path / "data.csv").open("a") as fh:
        for _ in range(30):
            fh.write("10,3,4,Layer 1 Up,0.38\n" * 100_000)
    code = textwrap.dedent(f"""
        import resource
        from milling_twin.orchestrator.scenario import load_scenario
        import pandas, fmpy  # imported before the baseline: loaded by the runs anyway
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        scenario = load_scenario({str(path)!r}, {str(fmu_dir)!r})
        after = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        print(len(scenario.recorded.time), (after - before) / 1024)
        """)
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    rows, grown_mb = proc.stdout.split()
    assert int(rows) == 3 and float(grown_mb) < 30.0, proc.stdout + proc.stderr


# ---- the other readers of user files: point clouds, recordings to reconstruct a program from ----


def test_point_clouds_and_recordings_to_reconstruct_or_fit_are_read_from_regular_files_only(tmp_path: Path) -> None:
    notes = tmp_path / "cloud.csv"
    notes.write_text(f"SECRET_TOKEN={SECRET}\n1\n2\n")
    code = textwrap.dedent(f"""
        from milling_twin.orchestrator.align.errors import AlignmentError
        from milling_twin.orchestrator.align.spatial import load_cloud_csv
        from milling_twin.orchestrator.gcode.reconstruct import reconstruct
        for path in ({str(notes)!r}, {str(fifo(tmp_path, "pipe.csv"))!r}):
            try:
                load_cloud_csv(path)
            except (AlignmentError, ValueError) as exc:
                print(exc)
        try:
            reconstruct({str(tmp_path / "pipe.csv")!r})
        except ValueError as exc:
            print(exc)
        from pathlib import Path
        from milling_twin.datasets import read_recording
        try:
            read_recording(Path({str(fifo(tmp_path, "6-n6000f300ap3ae25.csv"))!r}))
        except ValueError as exc:
            print(exc)
        """)
    try:
        proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    except subprocess.TimeoutExpired:
        pytest.fail("a FIFO blocked the reader")
    assert proc.stdout.splitlines() == [
        f"{notes}: not a CSV file (line 1 is not a header of comma-separated column names; looked for the columns "
        f"x, y, z)",
        f"{tmp_path / 'pipe.csv'} is a FIFO (named pipe), not a regular file (the CSV file must be one)",
        f"{tmp_path / 'pipe.csv'} is a FIFO (named pipe), not a regular file (the recording must be one)",
        f"{tmp_path / '6-n6000f300ap3ae25.csv'} is a FIFO (named pipe), not a regular file (the recording must be "
        f"one)"], \
        proc.stdout + proc.stderr
