"""The study layer in one process: study files (cases, sampling, errors naming file and key), case ids, the
summary, a failing case, --resume, the command. The dask cluster: tests/test_study_dask.py."""
from __future__ import annotations

import concurrent.futures
import json
import math
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pandas as pd
import pytest

from milling_twin.cli import main
from milling_twin.orchestrator.study.batching import TASK_SECONDS, BatchSizer
from milling_twin.orchestrator.study.cases import case_id
from milling_twin.orchestrator.study.executor import SerialExecutor, open_executor
from milling_twin.orchestrator.study.reduce import REDUCTIONS, get_reduction
from milling_twin.orchestrator.study.run import sweep
from milling_twin.orchestrator.study.spec import StudyError, load_study
from milling_twin.orchestrator.study.summary import SummaryStore

REPO = Path(__file__).resolve().parents[1]
CHATTER = REPO / "scenarios" / "chatter.toml"

HEAD = f"""\
[study]
name = "s"
base = "{CHATTER.as_posix()}"
stop_time = 0.005
"""
REDUCE = """
[[study.reduce]]
kind = "max"
variable = "force.Fx"
[[study.reduce]]
kind = "rms"
variable = "vibration.tip_displacement_y"
name = "tip_rms"
"""
GRID = """
[study.grid]
force.spindle_speed = { values = [5000, 7000], unit = "rpm" }
"force.axial_depth" = ["0.02mm", "0.05mm"]
"""


def write(tmp_path: Path, body: str, name: str = "study.toml") -> Path:
    path = tmp_path / name
    path.write_text(HEAD + body)
    return path


def test_a_grid_is_the_cartesian_product_in_si_with_stable_ids(tmp_path: Path, fmu_dir: Path) -> None:
    study = load_study(write(tmp_path, GRID + REDUCE), fmu_dir)
    assert study.variables == ("force.spindle_speed", "force.axial_depth")
    assert [c.values["force.axial_depth"] for c in study.cases] == [{"value": 0.02, "unit": "mm"},
                                                                   {"value": 0.05, "unit": "mm"}] * 2
    assert len({c.case_id for c in study.cases}) == 4
    # the id depends on the values (and the study's stop time), not on their order or on the file
    again = load_study(write(tmp_path, GRID.replace("[5000, 7000]", "[7000, 5000]") + REDUCE, "b.toml"), fmu_dir)
    assert {c.case_id for c in again.cases} == {c.case_id for c in study.cases}
    values = study.cases[0].values
    assert case_id(dict(reversed(list(values.items()))), 0.005) == study.cases[0].case_id
    assert case_id(values, 0.006) != study.cases[0].case_id


def test_lists_ranges_set_and_duplicates(tmp_path: Path, fmu_dir: Path) -> None:
    study = load_study(write(tmp_path, """
[study.set]
"force.feed_velocity_x" = "300mm/min"
[[study.grid]]
force.axial_depth = { start = 0.01, stop = 0.03, num = 3, unit = "mm" }
[[study.grid]]
force.axial_depth = { values = [0.01], unit = "mm" }
[study.list]
force.axial_depth = [0.00001, 0.00002]
force.n_flutes = [2, 3]
""" + REDUCE), fmu_dir)
    depths = [c.values["force.axial_depth"] for c in study.cases]
    # the second grid's 0.01 mm is the first grid's first case: one case
    assert depths == [{"value": 0.01, "unit": "mm"}, {"value": 0.02, "unit": "mm"}, {"value": 0.03, "unit": "mm"},
                      1e-05, 2e-05]
    assert all(c.values["force.feed_velocity_x"] == {"value": 300.0, "unit": "mm/min"} for c in study.cases)
    assert [c.values.get("force.n_flutes") for c in study.cases] == [None, None, None, 2, 3]


SAMPLE = """
[study.sample]
method = "{method}"
n = {n}
seed = {seed}
force.spindle_speed = {{ min = 5000, max = 8000, unit = "rpm" }}
force.n_flutes = {{ min = 1, max = 4 }}
"""


@pytest.mark.parametrize("method", ["lhs", "sobol"])
def test_samples_are_seeded_and_inside_their_ranges(tmp_path: Path, fmu_dir: Path, method: str) -> None:
    def cases(seed: int, name: str) -> list[dict]:
        body = SAMPLE.format(method=method, n=8, seed=seed) + REDUCE
        return [c.values for c in load_study(write(tmp_path, body, name), fmu_dir).cases]

    first, same, other = cases(1, "a.toml"), cases(1, "b.toml"), cases(2, "c.toml")
    assert first == same and first != other and len(first) == 8
    speeds = sorted(c["force.spindle_speed"]["value"] for c in first)
    assert 5000 <= speeds[0] and speeds[-1] <= 8000
    assert all(isinstance(c["force.n_flutes"], int) and 1 <= c["force.n_flutes"] <= 4 for c in first)
    if method == "lhs":  # one sample in each of the 8 strata of the range
        assert sorted(int((s - 5000) / 375) for s in speeds) == list(range(8))


def test_monte_carlo_draws_are_seeded(tmp_path: Path, fmu_dir: Path) -> None:
    body = """
[study.distributions]
n = 200
seed = 3
force.Ktc = { kind = "normal", mean = 767, std = 20, unit = "N/mm2" }
force.Krc = { kind = "uniform", min = 150, max = 180, unit = "N/mm2" }
force.Kac = { kind = "lognormal", median = 222, sigma = 0.1, unit = "N/mm2" }
""" + REDUCE
    a = load_study(write(tmp_path, body, "a.toml"), fmu_dir).cases
    b = load_study(write(tmp_path, body, "b.toml"), fmu_dir).cases
    assert [c.values for c in a] == [c.values for c in b]
    kt = pd.Series([c.values["force.Ktc"]["value"] for c in a])
    kr = pd.Series([c.values["force.Krc"]["value"] for c in a])
    ka = pd.Series([c.values["force.Kac"]["value"] for c in a])
    assert abs(kt.mean() - 767) < 5 and 15 < kt.std() < 25
    assert kr.between(150, 180).all()
    assert abs(ka.median() / 222 - 1) < 0.03 and (ka > 0).all()


@pytest.mark.parametrize(("body", "key", "message"), [
    ("[study.grid]\nforce.axial_depth = [1]\n[study.foo]\n", "study.foo", "unknown key 'foo'"),
    ("[study.grid]\nforce.spindle_speed = { values = [5000], unit = \"kg\" }\n",
     "[study.grid].force.spindle_speed", "does not fit"),
    ("[study.grid]\nforce.nope = [1.0]\n", "[study.grid].force.nope", "unknown variable 'nope'"),
    ("[study.grid]\nforce.axial_depth = [\"200mm\"]\n", "[study.grid].force.axial_depth", "outside the range"),
    ("[study.list]\nforce.axial_depth = [1e-5, 2e-5]\nforce.n_flutes = [2]\n", "[study.list].force.n_flutes",
     "1 values, but force.axial_depth has 2"),
    ("[study.sample]\nmethod = \"sobol\"\nn = 6\nforce.axial_depth = { min = 0, max = 1, unit = \"mm\" }\n",
     "[study.sample].n", "power of 2"),
    ("[study.sample]\nmethod = \"grid\"\nn = 4\n", "[study.sample].method", "lhs"),
    ("[study.distributions]\nn = 4\nforce.Ktc = { kind = \"normal\", mean = 700 }\n",
     "[study.distributions].force.Ktc.std", "finite number"),
    ("[study.grid]\nforce.axial_depth = [1e-5]\n[[study.reduce]]\nkind = \"max\"\nvariable = \"force.torque\"\n",
     "[[study.reduce]][0].variable", "not a recorded output"),
    ("[study.grid]\nforce.axial_depth = [1e-5]\n[[study.reduce]]\nkind = \"max\"\nvariable = \"force.Fx\"\n"
     "window = 1\n",
     "[[study.reduce]][0].window", "unknown key"),
    ("[study.grid]\nforce.axial_depth = [1e-5]\n[[study.reduce]]\nkind = \"maxx\"\n",
     "[[study.reduce]][0].kind", "unknown reduction"),
    ("[study.grid]\nforce.axial_depth = [1e-5]\n[[study.reduce]]\nkind = \"machining_time\"\nwindow = 2\n",
     "[[study.reduce]][0]", "window"),
    ("[study.grid]\nforce.axial_depth = [1e-5]\n[[study.reduce]]\nkind = \"rms_error\"\n",
     "[[study.reduce]][0].kind", "needs [[compare]] pairs"),
    ("", "study", "no cases"),
])
def test_bad_study_files_name_the_file_and_the_key(tmp_path: Path, fmu_dir: Path, body: str, key: str,
                                                  message: str) -> None:
    reduce = "" if "study.reduce" in body else REDUCE
    path = write(tmp_path, body + reduce)
    with pytest.raises(StudyError) as info:
        load_study(path, fmu_dir)
    assert info.value.path == path and info.value.key == key, str(info.value)
    assert message in info.value.detail
    assert str(info.value).startswith(f"{path}: {key}: ")


def test_a_missing_base_and_a_scenario_given_as_study(tmp_path: Path, fmu_dir: Path) -> None:
    path = tmp_path / "s.toml"
    path.write_text('[study]\nname = "s"\nbase = "nowhere.toml"\n')
    with pytest.raises(StudyError, match=r"s.toml: study.base: no scenario file .*nowhere.toml"):
        load_study(path, fmu_dir)
    with pytest.raises(StudyError, match=r"chatter.toml: study: missing required table \[study\] \(a scenario"):
        load_study(CHATTER, fmu_dir)


def test_the_serial_executor_hands_back_results_and_exceptions() -> None:
    with open_executor(workers=0) as executor:
        assert isinstance(executor, SerialExecutor)
        ok, bad = executor.submit(pow, 2, 10), executor.submit(int, "x")
        assert ok.result() == 1024 and isinstance(bad.exception(), ValueError)
        assert [f.result() for f in concurrent.futures.as_completed([ok])] == [1024]
    with pytest.raises(RuntimeError, match="after shutdown"):
        executor.submit(pow, 2, 2)
    with pytest.raises(ValueError, match="workers=-1"):
        with open_executor(workers=-1):
            pass
    with pytest.raises(ValueError, match="choose one"):
        with open_executor(workers=2, scheduler="tcp://127.0.0.1:1"):
            pass


def test_tasks_grow_from_one_case_to_the_aim_and_shrink_at_the_end() -> None:
    sizer = BatchSizer(slots=2)
    assert sizer.size(240) == 1  # nothing measured yet
    for wall in (0.04, 0.05, 0.06, math.nan):  # a lost case (NaN) does not count
        sizer.record(wall)
    assert sizer.size(240) == round(TASK_SECONDS / 0.05) == 5
    assert sizer.size(12) == 3 and sizer.size(1) == 1  # the last tasks: ceil(remaining / (2 x slots))
    for wall in (0.0, 0.0, 0.0):  # median of 0, 0, 0, 0.04, 0.05, 0.06: 0.02 s, so 12.5 cases
        sizer.record(wall)
    assert sizer.size(1000) == 12
    assert BatchSizer(slots=1, max_cases=4).size(100) == 1
    fast = BatchSizer(slots=1, max_cases=4)
    fast.record(0.0)
    assert fast.size(100) == 4
    with pytest.raises(ValueError, match="nothing to size"):
        sizer.size(0)


def test_a_task_of_several_cases_that_fails_as_a_task_runs_them_again_one_by_one(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A cluster gets tasks of several cases once the first have been timed; a task that fails as a task (its
    worker lost, here an exception outside any case's own handling) is split, so only the case that fails alone
    is a failed row, every other case has its row."""
    from tqdm import tqdm

    from milling_twin.orchestrator.study import run as study_run
    from milling_twin.orchestrator.study.spec import Case

    tasks = [study_run.CaseTask(Case(f"c{i:02d}", {}, "test"), None, tmp_path / "cases", (), ())  # type: ignore
             for i in range(40)]
    batches: list[int] = []

    def fake_run_case(task: study_run.CaseTask) -> dict:
        if task.case.case_id == "c20":
            raise RuntimeError("worker lost")
        return {"case_id": task.case.case_id, "status": "ok", "error": "", "run_status": "completed",
                "wall_time": 0.01, "run_dir": str(task.cases_dir / task.case.case_id)}

    def counted(batch: tuple) -> list:
        batches.append(len(batch))
        return [fake_run_case(task) for task in batch]

    monkeypatch.setattr(study_run, "run_cases", counted)
    store = SummaryStore(tmp_path / "study")
    with concurrent.futures.ThreadPoolExecutor(2) as executor:
        study_run._dispatch(executor, tasks, store, tqdm(disable=True))
    rows = store.rows()
    assert sorted(rows) == [t.case.case_id for t in tasks]
    assert [cid for cid, row in rows.items() if row["status"] != "ok"] == ["c20"]
    assert rows["c20"]["error"] == "RuntimeError: worker lost"
    assert batches[0] == 1 and max(batches) > 1 and batches.count(1) > 4  # batched, then split


def test_the_summary_kept_in_memory_is_the_one_on_disk(tmp_path: Path) -> None:
    store = SummaryStore(tmp_path / "study")
    rows = [{"case_id": f"c{i}", "status": "ok" if i else "failed", "error": "" if i else "E: no", "x": 0.5 * i,
             "n": i, "y": math.nan if i == 1 else float(i), "run_status": "completed", "wall_time": 0.1,
             "run_dir": f"c{i}"} for i in range(3)]
    store.clear()
    for row in rows:
        store.write(row)
    store.write({**rows[0], "status": "ok", "error": ""})  # a case run again replaces its row
    kept = store.consolidate(["c2", "c0", "c1"], ["x", "n"])
    read = SummaryStore(tmp_path / "study").consolidate(["c2", "c0", "c1"], ["x", "n"])
    pd.testing.assert_frame_equal(kept, read, check_exact=True)
    assert list(kept["case_id"]) == ["c2", "c0", "c1"] and kept.loc[1, "status"] == "ok"


def test_reductions_are_registered_by_name() -> None:
    assert {"max", "min", "mean", "rms", "machining_time", "rms_error"} <= set(REDUCTIONS)
    assert get_reduction("math:hypot")(3, 4) == 5
    with pytest.raises(KeyError, match="unknown reduction"):
        get_reduction("nope")


FAILING = """
[study.list]
force.history_size = [16384, 16]
"""


def test_a_failing_case_is_a_row_with_its_message_and_the_study_goes_on(tmp_path: Path, fmu_dir: Path) -> None:
    study = load_study(write(tmp_path, FAILING + REDUCE), fmu_dir)
    result = sweep(study, tmp_path / "out", workers=0, progress=False)
    rows = result.summary.set_index("force.history_size")
    assert list(rows["status"]) == ["ok", "failed"] and result.failed == 1
    assert rows.loc[16384, "error"] == "" and rows.loc[16384, "max_force.Fx"] > 0
    assert rows.loc[16, "error"].startswith("SimulationError: DoStep of instance 'force'")
    assert "history_size = 16 samples" in rows.loc[16, "error"]
    assert pd.isna(rows.loc[16, "max_force.Fx"])


def test_resume_runs_only_the_cases_not_finished(tmp_path: Path, fmu_dir: Path) -> None:
    study = load_study(write(tmp_path, GRID + REDUCE), fmu_dir)
    out = tmp_path / "out"
    full = sweep(study, out, workers=0, progress=False)
    assert full.ran == 4 and full.failed == 0
    # where the time went: the phases in order (no refinement, no post-processor), together the sweep's wall time
    assert list(full.phases) == ["executor start", "cases", "executor close"]
    assert all(t >= 0 for t in full.phases.values()) and 0 < sum(full.phases.values()) <= full.wall_time
    parts = sorted((full.folder / "summary").glob("*.parquet"))
    assert len(parts) == 4
    # a study killed after two cases: two rows in summary/
    for part in parts[2:]:
        part.unlink()
    kept = {p.stem: (full.folder / "cases" / p.stem / "run.json").stat().st_mtime_ns for p in parts[:2]}
    resumed = sweep(study, out, workers=0, resume=True, progress=False)
    assert (resumed.ran, resumed.skipped) == (2, 2)
    assert {cid: (full.folder / "cases" / cid / "run.json").stat().st_mtime_ns for cid in kept} == kept
    columns = [c for c in full.summary.columns if c != "wall_time"]
    pd.testing.assert_frame_equal(resumed.summary[columns], full.summary[columns])
    assert list(pd.read_csv(full.folder / "summary.csv")["case_id"]) == [c.case_id for c in study.cases]
    # without --resume everything runs again
    assert sweep(study, out, workers=0, progress=False).ran == 4


def test_the_sweep_command(tmp_path: Path, fmu_dir: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = write(tmp_path, FAILING + REDUCE)
    out = tmp_path / "out"
    assert main(["sweep", str(path), "--fmu-dir", str(fmu_dir), "--out", str(out), "--workers", "0",
                 "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "s: 2 of 2 cases in the summary (2 run, 0 finished before), 1 failed" in text
    assert "failed " in text and "history_size = 16 samples" in text
    assert re.search(r"on serial, in this process \(executor start [0-9.e-]+ s, cases [0-9.e-]+ s, executor close", text)
    assert (out / "s" / "summary.parquet").is_file() and (out / "s" / "summary.csv").is_file()
    bad = write(tmp_path, "[study.grid]\nforce.nope = [1.0]\n" + REDUCE, "bad.toml")
    assert main(["sweep", str(bad), "--fmu-dir", str(fmu_dir), "--workers", "0"]) == 2
    assert "bad.toml: [study.grid].force.nope: unknown variable" in capsys.readouterr().err


def test_a_study_resumed_after_sigkill_gives_the_uninterrupted_summary(tmp_path: Path, fmu_dir: Path) -> None:
    path = write(tmp_path, """
[study.list]
force.axial_depth = ["0.01mm", "0.02mm", "0.03mm", "0.04mm", "0.05mm", "0.06mm"]
""" + REDUCE)
    path.write_text(path.read_text().replace("stop_time = 0.005", "stop_time = 0.5"))
    study = load_study(path, fmu_dir)
    parts = tmp_path / "killed" / "s" / "summary"
    proc = subprocess.Popen([sys.executable, "-m", "milling_twin", "sweep", str(path), "--fmu-dir", str(fmu_dir),
                             "--out", str(tmp_path / "killed"), "--workers", "0", "--no-progress"],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while len(list(parts.glob("*.parquet"))) < 2 and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.005)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait()
    finished = len(list(parts.glob("*.parquet")))
    assert proc.returncode == -signal.SIGKILL and 2 <= finished < 6, (proc.returncode, finished)
    resumed = sweep(study, tmp_path / "killed", workers=0, resume=True, progress=False)
    assert (resumed.ran, resumed.skipped) == (6 - finished, finished)
    whole = sweep(study, tmp_path / "whole", workers=0, progress=False)
    columns = [c for c in whole.summary.columns if c not in ("wall_time", "run_dir")]
    pd.testing.assert_frame_equal(resumed.summary[columns], whole.summary[columns], check_exact=True)


def test_a_whole_part_study_reduces_the_process_report(tmp_path: Path, fmu_dir: Path) -> None:
    from cases.part_case import write_part

    part = write_part(tmp_path)
    path = tmp_path / "part_study.toml"
    path.write_text(f"""
[study]
name = "part_feed"
base = "{part.name}"
[study.list]
interp.feed_override = [1.2]
[[study.reduce]]
kind = "machining_time"
[[study.reduce]]
kind = "process_report"
fields = ["cutting_time", "removed_volume"]
[[study.reduce]]
kind = "max"
variable = "force.Fx"
where = "workpiece.axial_depth"
""")
    result = sweep(load_study(path, fmu_dir), tmp_path / "out", workers=0, progress=False)
    row = result.summary.iloc[0]
    assert row["status"] == "ok", row["error"]
    # json, not pandas.read_json: pandas parses floats to within an ulp or two (precise_float=False)
    report = json.loads((result.folder / "cases" / row["case_id"] / "process_report.json").read_text())
    assert row["machining_time"] == report["machining_time"] and row["cutting_time"] == report["cutting_time"]
    assert 0 < row["cutting_time"] < row["machining_time"] and row["removed_volume"] > 0
    assert row["max_force.Fx"] > 0
    bad = path.read_text().replace('fields = ["cutting_time", "removed_volume"]', 'fields = ["speed"]')
    path.write_text(bad)
    with pytest.raises(StudyError, match=r"\[\[study.reduce\]\]\[1\].fields: expected a list of machining_time"):
        load_study(path, fmu_dir)


def _count_check(table: dict, where: str) -> int:
    for key, value in table.items():
        if key != "least" or not isinstance(value, int):
            raise ValueError(f"{where}: [study.count].{key} = {value!r}: expected least = <whole number>")
    return table.get("least", 0)


def test_a_post_processor_runs_after_the_cases_with_its_table(tmp_path: Path, fmu_dir: Path) -> None:
    from milling_twin.orchestrator.study.post import POSTS, register_post

    seen: list[tuple[int, int, Path, int]] = []

    @register_post("count_ok", table="count", check=_count_check)
    def count_ok(summary: pd.DataFrame, study, folder: Path, least: int, executor) -> None:  # noqa: ANN001
        # the study's executor, still open: the post-processor's own work may use the workers
        seen.append((int((summary["status"] == "ok").sum()), least, folder, executor.submit(len, "abc").result()))

    try:
        path = write(tmp_path, GRID + REDUCE + "[study.count]\nleast = 3\n")
        path.write_text(path.read_text().replace('stop_time = 0.005\n', 'stop_time = 0.005\npost = "count_ok"\n'))
        result = sweep(load_study(path, fmu_dir), tmp_path / "out", workers=0, progress=False)
        assert seen == [(4, 3, result.folder, 3)]
        assert list(result.phases) == ["executor start", "cases", "post-processing", "executor close"]
        path.write_text(path.read_text().replace("least = 3", "least = \"x\""))
        with pytest.raises(StudyError) as info:
            load_study(path, fmu_dir)
        assert info.value.key == "[study.count].least = 'x'" and "expected least" in info.value.detail
        path.write_text(path.read_text().replace('post = "count_ok"', 'post = "nope"'))
        with pytest.raises(StudyError, match=r"study.post: unknown post-processor 'nope'"):
            load_study(path, fmu_dir)
        path.write_text(path.read_text().replace('post = "nope"\n', ''))
        with pytest.raises(StudyError, match=r"study.count: unknown key 'count'"):
            load_study(path, fmu_dir)
    finally:
        POSTS.pop("count_ok", None)
