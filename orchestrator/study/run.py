"""Running a study: every case through the executor, the summary written as cases finish.

:func:`sweep` submits the cases to :func:`~milling_twin.orchestrator.study.executor.open_executor` (the embedded dask
cluster, N local workers, an existing scheduler, or serially in this process), several per task on a cluster
(:func:`run_cases`, sized by :mod:`~milling_twin.orchestrator.study.batching`). On the worker a case is the ordinary
run: the base scenario with the case's values (``with_values``, named by the case id), run by the master into
``<out>/<study>/cases/<case id>/`` (Parquet, run.json, the report), then reduced there; only the summary row comes
back. A case that fails (an invalid value, an FMU error, a reduction that raises, a worker lost
more often than dask retries) gives a row with status "failed" and the message; the study goes on.
"""
from __future__ import annotations

import logging
import math
import time
import traceback
from collections import deque
from collections.abc import Callable, Mapping
from contextlib import nullcontext
from concurrent.futures import FIRST_COMPLETED, Executor, Future, wait
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd
from tqdm import tqdm

from milling_twin.orchestrator.results import RunFolder
from milling_twin.orchestrator.scenario import Scenario
from milling_twin.orchestrator.study.batching import BatchSizer
from milling_twin.orchestrator.study.executor import SerialExecutor, executor_slots, open_executor
from milling_twin.orchestrator.study.reduce import CaseRun, get_reduction
from milling_twin.orchestrator.study.refine import refined_values
from milling_twin.orchestrator.study.spec import Case, ReduceSpec, Study, StudyError
from milling_twin.orchestrator.study.summary import SummaryStore

__all__ = ["CaseTask", "StudyResult", "run_case", "run_cases", "si_inputs", "sweep"]

_log = logging.getLogger(__name__)

CASES = "cases"

# What a sweep's wall time is spent on, in order (StudyResult.phases): opening the executor (a cluster's start, its
# workers' imports), the post-processor's preparation (serially: its work; on a cluster: submitting it to fill the
# workers' idle moments), the cases, the refinement rounds, the post-processor, closing the executor. On a cluster
# the first and last are the fixed cost that parallel cases must earn back (docs/studies.md#measured).
PHASES = ("executor start", "post preparation", "cases", "refinement", "post-processing", "executor close")


@dataclass(frozen=True)
class CaseTask:
    """What a worker needs for one case (pickled to it; paths absolute)."""

    case: Case
    scenario: Scenario  # the study's base scenario (stop time applied)
    cases_dir: Path
    reductions: tuple[ReduceSpec, ...]
    inputs: tuple[str, ...]  # the study's variables: the summary's input columns
    stepping: str = "auto"


@dataclass(frozen=True)
class StudyResult:
    name: str
    folder: Path  # <out>/<study name>
    summary: pd.DataFrame  # the consolidated summary (summary.parquet)
    ran: int  # cases run by this sweep
    skipped: int  # cases finished before (--resume)
    failed: int  # rows with status "failed"
    wall_time: float  # s, the sweep (cluster start included)
    workers: int | None  # the executor's size when known (0: serial)
    phases: Mapping[str, float] = field(default_factory=dict)  # s per phase of the sweep, in order (PHASES)

    @property
    def summary_file(self) -> Path:
        return self.folder / "summary.parquet"


def si_inputs(scenario: Scenario, names: tuple[str, ...]) -> dict[str, Any]:
    """The values of ``names`` ("instance.variable", a parameter or a constant input) in ``scenario``, SI."""
    out: dict[str, Any] = {}
    for name in names:
        instance, _, variable = name.partition(".")
        inst = scenario.instance(instance)
        out[name] = inst.parameters.get(variable, inst.inputs.get(variable))
    return out


def _message(exc: BaseException) -> str:
    text = str(exc) or traceback.format_exception_only(type(exc), exc)[-1].strip()
    return f"{type(exc).__name__}: {text}"


def _check_outputs(spec: ReduceSpec, outputs: Any) -> dict[str, float]:
    if not isinstance(outputs, Mapping):
        raise TypeError(f"{spec.key} ({spec.kind}) returned {type(outputs).__name__}, not a dict of numbers")
    checked = {}
    for name, value in outputs.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise TypeError(f"{spec.key} ({spec.kind}) gave {name!r} = {value!r}, not a number")
        checked[str(name)] = float(value)
    return checked


def run_case(task: CaseTask) -> dict[str, Any]:
    """One case on a worker: run, reduce, and the summary row (never raises for the case's own failures)."""
    from milling_twin.api import simulate
    from milling_twin.orchestrator.scenario import with_values

    t0 = time.perf_counter()
    case = task.case
    row: dict[str, Any] = {"case_id": case.case_id, "status": "failed", "error": "",
                           **{name: None for name in task.inputs}}
    outputs: dict[str, float] = {}
    run_status = ""
    try:
        scenario = with_values(task.scenario, case.values, name=case.case_id)
        row.update(si_inputs(scenario, task.inputs))
        results = simulate(scenario, out=task.cases_dir, stepping=task.stepping, progress=False)
        run_status = results.status
        if results.run.signal is not None:  # SIGINT/SIGTERM/SIGHUP stop the study (this case's rows are kept)
            raise KeyboardInterrupt(f"{results.run.signal} during case {case.case_id}")
        if results.status == "interrupted":
            raise RuntimeError("the run was interrupted")
        done = CaseRun(case.case_id, dict(case.values), results.scenario, Path(results.run_dir), results.status,
                       results.run, results.frame)
        for spec in task.reductions:
            try:
                values = get_reduction(spec.kind)(done, **spec.options)
            except Exception as exc:  # noqa: BLE001 - the case fails with the reduction's message
                raise RuntimeError(f"{spec.key} ({spec.kind}): {_message(exc)}") from exc
            outputs.update(_check_outputs(spec, values))
        row["status"] = "ok"
    except Exception as exc:  # noqa: BLE001 - a failed case is a row of the summary, the study goes on
        row["error"] = _message(exc)
    row.update(outputs)
    row.update(run_status=run_status, wall_time=time.perf_counter() - t0,
               run_dir=str(task.cases_dir / case.case_id))
    return row


def run_cases(tasks: tuple[CaseTask, ...]) -> list[dict[str, Any]]:
    """Several cases in one task on a worker (:mod:`~milling_twin.orchestrator.study.batching`): their rows."""
    return [run_case(task) for task in tasks]


def _lost_row(task: CaseTask, exc: BaseException) -> dict[str, Any]:
    """The row of a case whose task itself failed (its worker died more often than dask retries, say)."""
    return {"case_id": task.case.case_id, "status": "failed", "error": _message(exc),
            **{name: None for name in task.inputs}, "run_status": "", "wall_time": math.nan,
            "run_dir": str(task.cases_dir / task.case.case_id)}


SLOTS_SECONDS = 1.0  # how often a dispatch asks the cluster again how many workers it has


def _dispatch(executor: Executor, tasks: list[CaseTask], store: SummaryStore, bar: tqdm) -> None:
    """Run the cases and write each row as its task finishes. The serial executor runs one case as it is submitted;
    a cluster gets tasks of several cases (sized by :class:`BatchSizer` from the case times so far), two per worker
    thread in flight so that none waits for this process. A task of several cases that fails as a task (its worker
    killed more often than dask retries) is split: its cases run again one per task, so only a case that kills its
    workers itself ends as a failed row."""
    serial = isinstance(executor, SerialExecutor)
    slots, asked = executor_slots(executor), time.monotonic()
    sizer = BatchSizer(slots)
    pending: dict[Future, tuple[CaseTask, ...]] = {}
    queue: deque[tuple[CaseTask, ...]] = deque()  # single cases of split tasks, first
    todo = deque(tasks)
    while True:
        if not serial and time.monotonic() - asked > SLOTS_SECONDS:
            slots, asked = executor_slots(executor), time.monotonic()
            sizer.slots = slots
        window = 1 if serial else 2 * slots
        while (queue or todo) and len(pending) < window:
            if queue:
                batch = queue.popleft()
            else:
                batch = tuple(todo.popleft() for _ in range(1 if serial else sizer.size(len(todo))))
            pending[executor.submit(run_cases, batch)] = batch
        if not pending:
            return
        finished, _ = wait(pending, return_when=FIRST_COMPLETED)
        for future in finished:
            batch = pending.pop(future)
            try:
                rows = future.result()
            except Exception as exc:  # noqa: BLE001 - the task (not a case) failed: recorded, the study goes on
                if len(batch) > 1:
                    queue.extend((task,) for task in batch)
                    continue
                rows = [_lost_row(batch[0], exc)]
            for row in rows:
                if row["status"] != "ok":
                    _log.info("case %s failed: %s", row["case_id"], row["error"])
                store.write(row)
                sizer.record(row["wall_time"])
            bar.update(len(rows))


def _study_doc(study: Study, cases: list[Case], workers: int | None, scheduler: str | None) -> dict[str, Any]:
    refine = None if study.refine is None else {k: v for k, v in vars(study.refine).items() if k != "key"}
    return {"study": str(study.path.resolve()), "name": study.name, "description": study.description,
            "base": str(study.base.path), "stop_time": study.stop_time, "variables": list(study.variables),
            "reductions": [{"kind": r.kind, **r.options} for r in study.reductions], "refine": refine,
            "workers": workers, "scheduler": scheduler,
            "cases": [{"case_id": c.case_id, "source": c.source, "values": c.values} for c in cases]}


def _run_cases(executor: Executor, study: Study, cases: list[Case], done: set[str], store: SummaryStore,
               folder: Path, stepping: str, progress: bool, desc: str) -> int:
    """Run those of ``cases`` not in ``done``, each row written as it finishes; the number run."""
    todo = [case for case in cases if case.case_id not in done]
    if todo:
        base, cases_dir = study.scenario(), folder / CASES
        tasks = [CaseTask(case, base, cases_dir, study.reductions, study.variables, stepping) for case in todo]
        with tqdm(total=len(tasks), unit="case", desc=desc, disable=not progress) as bar:
            _dispatch(executor, tasks, store, bar)
    return len(todo)


def _refine(executor: Executor, study: Study, cases: list[Case], done: set[str], store: SummaryStore,
            folder: Path, stepping: str, progress: bool, doc: Callable[[], dict[str, Any]]) -> int:
    """The rounds of ``[study.refine]``: each adds its cases to ``cases`` (in place) and runs them; the number run."""
    spec, ran = study.refine, 0
    assert spec is not None
    for round_number in range(1, spec.rounds + 1):
        summary = store.consolidate([c.case_id for c in cases], study.variables)
        known = {c.case_id: c for c in cases}
        try:
            made = refined_values(summary, spec, study.variables, {k: c.values for k, c in known.items()},
                                  study.stop_time)
        except KeyError as exc:
            raise StudyError(study.path, f"{spec.key}.output", exc.args[0]) from None
        new = [Case(cid, values, f"{spec.key} round {round_number}") for cid, values in made if cid not in known]
        if not new:
            break
        cases.extend(new)
        store.write_study(doc())
        ran += _run_cases(executor, study, new, done, store, folder, stepping, progress,
                          f"{study.name} refine {round_number}/{spec.rounds}")
    return ran


def sweep(study: Study, out: str | Path, *, workers: int | None = None, scheduler: str | None = None,
          resume: bool = False, progress: bool = True, stepping: str = "auto") -> StudyResult:
    """Run ``study``'s cases into ``out/<study name>/`` (see the module docstring); with ``resume`` the cases whose
    summary row says "ok" are skipped, the others run again."""
    t0 = time.perf_counter()
    folder = (Path(out) / study.name).resolve()
    with RunFolder.claim(folder, what="study"):  # one sweep per study folder at a time (its cases claim theirs)
        return _sweep(study, folder, workers, scheduler, resume, progress, stepping, t0)


def _sweep(study: Study, folder: Path, workers: int | None, scheduler: str | None, resume: bool, progress: bool,
           stepping: str, t0: float) -> StudyResult:
    store = SummaryStore(folder)
    if resume:
        done = store.finished_ok()
    else:
        store.clear()
        done = set()
    cases = list(study.cases)  # [study.refine] adds its rounds' cases

    def doc() -> dict[str, Any]:
        return _study_doc(study, cases, workers, scheduler)

    store.write_study(doc())
    (folder / CASES).mkdir(parents=True, exist_ok=True)
    post = None
    if study.post is not None:
        from milling_twin.orchestrator.study.post import get_post

        post = get_post(study.post)
    needed = post is not None or study.refine is not None or any(c.case_id not in done for c in cases)
    ran = 0
    clock = _PhaseClock()
    with open_executor(workers, scheduler) if needed else nullcontext() as executor:
        clock.lap("executor start")
        prepared = () if post is None or post.prepare is None else (
            post.prepare(study, study.post_config, executor),)
        if prepared:
            clock.lap("post preparation")
        try:
            ran += _run_cases(executor, study, cases, done, store, folder, stepping, progress, study.name)
            clock.lap("cases")
            if study.refine is not None:
                ran += _refine(executor, study, cases, done, store, folder, stepping, progress, doc)
                clock.lap("refinement")
        finally:
            summary = store.consolidate([c.case_id for c in cases], study.variables)
        if post is not None:  # on the same executor: its own parallel work (the map's references) uses the workers
            try:
                post.run(summary, study, folder, study.post_config, executor, *prepared)
            except Exception as exc:
                exc.add_note(f"post-processor {study.post!r} of {study.path}; the summary is written: "
                             f"{folder / 'summary.parquet'}")
                raise
            clock.lap("post-processing")
    clock.lap("executor close")
    return StudyResult(study.name, folder, summary, ran, len(cases) - ran,
                       int((summary["status"] != "ok").sum()), time.perf_counter() - t0, workers, clock.phases)


@dataclass
class _PhaseClock:
    """Wall time per phase of a sweep: each :meth:`lap` ends the phase it names (started by the previous lap)."""

    phases: dict[str, float] = field(default_factory=dict)
    _last: float = field(default_factory=time.perf_counter)

    def lap(self, phase: str) -> None:
        assert phase in PHASES, phase
        now = time.perf_counter()
        self.phases[phase] = now - self._last
        self._last = now
