"""The Python API: one call to simulate a scenario, one to calibrate, one to load results.

    import milling_twin as mt
    results = mt.simulate("scenarios/umich_power.toml", overrides={"power.P_idle": {"value": 0.25, "unit": "kW"}})
    results.frame["power.P_total"]            # SI (W); results.frame.attrs["display_units"]["power.P_total"] == "kW"
    cal = mt.calibrate("scenarios/calibration/umich_power.toml", out="runs")

The command line (``milling-twin run``, ``milling-twin calibrate``) is built on these functions.
"""
from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

if TYPE_CHECKING:  # the heavy modules load when a function is called, not on `import milling_twin`
    import pandas as pd

    from milling_twin.orchestrator.calibrate.result import CalibrationResult
    from milling_twin.orchestrator.master import RunResult
    from milling_twin.orchestrator.part.report import ProcessReport
    from milling_twin.orchestrator.report import Report
    from milling_twin.orchestrator.results import RunFolder
    from milling_twin.orchestrator.scenario import Scenario
    from milling_twin.orchestrator.study.run import StudyResult

__all__ = ["Results", "calibrate", "default_fmu_dir", "load_results", "load_scenario", "optimize", "simulate",
           "sweep"]

FMU_DIR_ENV = "MILLING_TWIN_FMU_DIR"


def default_fmu_dir() -> Path:
    """$MILLING_TWIN_FMU_DIR, else build/fmus (relative to the working directory) when it exists, else the FMUs
    installed with the package (a wheel's milling_twin/fmus/), else build/fmus (which errors then name)."""
    env = os.environ.get(FMU_DIR_ENV)
    if env:
        return Path(env)
    build = Path("build/fmus")
    if build.is_dir():
        return build
    from milling_twin.orchestrator.packaged import packaged_fmu_dir

    return packaged_fmu_dir() or build


@dataclass(frozen=True)
class Results:
    """A finished (or interrupted) run: its rows, how it ran, and the comparison with the recording."""

    frame: pd.DataFrame  # one row per output time, SI; frame.attrs["units"], frame.attrs["display_units"]
    run: RunResult  # status, steps, wall time, stepping path
    scenario: Scenario  # as run (overrides and parameter sets applied)
    report: Report | None  # recorded-vs-simulated comparisons, when the scenario has [[compare]]
    run_dir: Path | None  # where the results are, None when they were kept in memory only
    process_report: ProcessReport | None = None  # a whole-part scenario's per-block report (docs/process_report.md)

    @property
    def status(self) -> str:
        """"completed", "interrupted" or "terminated: ..." (an FMU ended the run)."""
        return self.run.status

    @property
    def steps(self) -> int:
        """Base-grid steps done."""
        return self.run.steps


def load_scenario(path: str | Path, fmu_dir: str | Path | None = None, *,
                  parameter_sets: Sequence[str | Path] = (),
                  overrides: Mapping[str, Any] | None = None,
                  recording: str | Path | None = None) -> Scenario:
    """A scenario file, checked; ``parameter_sets`` are applied after its own, then ``overrides``
    (``{"instance.variable": value}``, a value in SI or ``{"value": v, "unit": "kW"}``). ``recording``: a
    recording of the same machine and logger read instead of the scenario's ``[recorded].file``."""
    from milling_twin.orchestrator.scenario import load_scenario as load, with_values

    scenario = load(path, fmu_dir if fmu_dir is not None else default_fmu_dir(), parameter_sets=parameter_sets,
                    recording=recording)
    return with_values(scenario, overrides) if overrides else scenario


def load_results(path: str | Path) -> pd.DataFrame:
    """The rows of a run folder (also of a killed run: every completed chunk), with units in ``attrs``."""
    from milling_twin.orchestrator.results import load_results as load

    return load(path)


def simulate(scenario: Scenario | str | Path, *, fmu_dir: str | Path | None = None,
             overrides: Mapping[str, Any] | None = None, parameter_sets: Sequence[str | Path] = (),
             out: str | Path | None = None, stepping: str = "auto", progress: bool = False,
             fmi_call_logger: Callable[[str], None] | None = None, if_busy: str = "refuse") -> Results:
    """Co-simulate a scenario (a file or a loaded :class:`Scenario`).

    ``out``: results go to ``out/<scenario name>/`` (Parquet chunks, run.json, the report and its plots);
    None keeps them in memory only. ``stepping``: "auto", "fast" or "python". ``fmi_call_logger`` receives
    every FMI call (the python stepping loop runs). Raises ``SimulationError`` when an FMU call fails
    (with ``out``, the rows so far are on disk) and ``ScenarioError`` for an invalid scenario or override.
    The run owns its folder until its report is written; ``if_busy``: what to do when another run owns it,
    "refuse" (raise ``RunFolderBusy``), "wait" or "new" (a new folder ``<name>-2``, ...; ``Results.run_dir``).
    """
    from milling_twin.orchestrator.master import run
    from milling_twin.orchestrator.scenario import with_values

    if isinstance(scenario, (str, Path)):
        scenario = load_scenario(scenario, fmu_dir, parameter_sets=parameter_sets, overrides=overrides)
    else:
        if parameter_sets:
            raise ValueError("parameter_sets apply to a scenario file; pass its path, or use overrides")
        if overrides:
            scenario = with_values(scenario, overrides)
    if out is None:
        with tempfile.TemporaryDirectory(prefix="milling-twin-") as folder:
            results = _run_and_report(run, scenario, Path(folder), stepping, progress, fmi_call_logger, if_busy)
            return Results(results.frame, results.run, results.scenario, results.report, None)
    return _run_and_report(run, scenario, Path(out), stepping, progress, fmi_call_logger, if_busy)


def _run_and_report(run: Callable[..., RunResult], scenario: Scenario, out: Path, stepping: str, progress: bool,
                    fmi_call_logger: Callable[[str], None] | None, if_busy: str) -> Results:
    """The run and its reports in the run folder, owned (locked) from before the run until the reports are
    written (so that another run cannot start there in between)."""
    from milling_twin.orchestrator.results import RunFolder
    from milling_twin.orchestrator.safe_names import check_name

    check_name(scenario.name, f"{scenario.path}: [scenario].name")
    with RunFolder.claim(out / scenario.name, if_busy) as folder:
        return _reported(run, scenario, out, folder, stepping, progress, fmi_call_logger)


def _reported(run: Callable[..., RunResult], scenario: Scenario, out: Path, folder: RunFolder, stepping: str,
              progress: bool, fmi_call_logger: Callable[[str], None] | None) -> Results:
    """The run, then its comparisons with the recording and, for a whole-part scenario, the process report (the
    Workpiece writes its final Z-map into the run folder for it)."""
    zmap = None
    if scenario.part is not None:
        from milling_twin.orchestrator.part.model import WORKPIECE
        from milling_twin.orchestrator.scenario import with_values

        if "zmap_file" in scenario.instance(WORKPIECE).variables:
            zmap = (folder.path / "final_zmap.asc").resolve()
            scenario = with_values(scenario, {f"{WORKPIECE}.zmap_file": str(zmap)})
    from milling_twin.orchestrator.master import SimulationError

    try:
        result = run(scenario, out, progress=progress, stepping=stepping, fmi_call_logger=fmi_call_logger,
                     folder=folder)
    except SimulationError as exc:
        exc.run_dir = folder.path
        if scenario.part is not None:  # the blocks up to the failure: where and how the part went wrong
            exc.process_report = _partial_process_report(scenario, folder.path, exc)
        raise
    frame = load_results(result.run_dir)
    report = process = None
    if scenario.compare and result.rows:
        from milling_twin.orchestrator.report import write_report

        report = write_report(scenario, result.run_dir, frame)
    if scenario.part is not None and result.rows:
        from milling_twin.orchestrator.part.report import write_process_report

        process = write_process_report(scenario.part, frame, result.run_dir, zmap_file=zmap,
                                       comparisons=report.comparisons if report else ())
    return Results(frame, result, scenario, report, result.run_dir, process)


def _partial_process_report(scenario: Scenario, run_dir: Path, exc: Exception):
    """The process report of a whole-part run that failed, from the rows it wrote (None without any)."""
    from milling_twin.orchestrator.part.report import write_process_report

    try:
        frame = load_results(run_dir)
    except (OSError, ValueError):
        return None
    if frame.empty:
        return None
    return write_process_report(scenario.part, frame, run_dir, zmap_file=None,
                                warnings=[f"the run failed: {exc}; the table ends at t = {frame['time'].iloc[-1]:g} s"
                                          if "time" in frame.columns else f"the run failed: {exc}"])


def calibrate(spec: str | Path, *, fmu_dir: str | Path | None = None, out: str | Path = "runs",
              overrides: Mapping[str, Any] | None = None, write_set: str | Path | None = None,
              data: str | Path | None = None, progress: bool = False, workers: int | None = None,
              scheduler: str | None = None) -> CalibrationResult:
    """Calibrate the parameters a spec names against its recording: results, the parameter set and the
    report (HTML, Markdown) go to ``out/calibration/<name>/``; ``write_set`` also publishes the set there
    (e.g. the committed file the calibrated scenario applies). ``overrides`` change the scenario first.
    ``workers`` (0: serial) / ``scheduler``: instead of the spec's ``[solver]`` ones, where a fit through the
    FMUs runs its starts and finite-difference columns (the serial result, bit for bit)."""
    from milling_twin.orchestrator.calibrate.run import calibrate as run_calibration

    return run_calibration(spec, fmu_dir if fmu_dir is not None else default_fmu_dir(), out, data=data,
                           progress=progress, write_set=write_set, overrides=overrides, workers=workers,
                           scheduler=scheduler)


def optimize(part: str | Path, *, fmu_dir: str | Path | None = None, out: str | Path = "runs",
             objective: str | None = None, max_iterations: int | None = None, sub_blocks: bool | None = None,
             workers: int | None = 0, progress: bool = False, echo: Callable[[str], None] | None = None):
    """Optimize the feeds of a whole-part scenario's program block by block within its ``[optimize]`` limits,
    each step verified by re-simulating the part (docs/optimize.md): into ``out/optimize/<part name>/``.
    ``objective``: "time" or "force" (default: the file's, else "time"); ``sub_blocks``: split lines whose
    engagement changes (default: the file's, else True); ``workers``: the study layer's, for a chattering tool's
    simulated stability map (0: in this process; None: one per core); ``echo`` receives a line per iteration.
    Returns an ``OptimizeResult`` (the iterations, the best one, the optimized program and the report)."""
    from milling_twin.orchestrator.optimize.run import optimize as run

    return run(part, fmu_dir=fmu_dir if fmu_dir is not None else default_fmu_dir(), out=out, objective=objective,
               max_iterations=max_iterations, sub_blocks=sub_blocks, workers=workers, progress=progress,
               echo=echo)


def sweep(study: str | Path, *, fmu_dir: str | Path | None = None, out: str | Path = "runs",
          workers: int | None = None, scheduler: str | None = None, resume: bool = False,
          progress: bool = False) -> StudyResult:
    """Run a study file's cases (docs/studies.md) into ``out/<study name>/``: each case a run folder in ``cases/``,
    one summary row per case in ``summary.parquet`` (and ``summary/``, written as cases finish). ``workers``:
    None an embedded dask cluster sized to the machine, N local worker processes, 0 serially in this process;
    ``scheduler``: an existing dask cluster (address or scheduler file). ``resume`` skips the cases already ok.
    Raises ``StudyError`` (naming the file and key) for an invalid study; a failing case is a summary row."""
    from milling_twin.orchestrator.study.executor import start_fork_server

    start_fork_server(workers, scheduler)  # its workers' imports on another core while this process imports its own
    from milling_twin.orchestrator.study.run import sweep as run_study
    from milling_twin.orchestrator.study.spec import load_study

    loaded = load_study(study, fmu_dir if fmu_dir is not None else default_fmu_dir())
    return run_study(loaded, out, workers=workers, scheduler=scheduler, resume=resume, progress=progress)
