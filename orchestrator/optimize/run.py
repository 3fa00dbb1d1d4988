"""The feed optimizer: a whole-part scenario run, its feeds scheduled, the new program re-simulated, corrected.

:func:`optimize` runs the part as written (iteration 0), then repeats: each program line's feed factor from the
runs so far (``schedule.next_factors``), the program rewritten with those feeds (``program_edit.rewrite_feeds``:
only F words change), the part run again with it through the whole-part twin. It stops when the factors no
longer change, when two runs in a row meet every limit with the same objective (within 0.2 %), or after
``max_iterations``;
the result is the best run that meets every limit (objective "time": the shortest; "force": the lowest peak
force whose cycle is no longer than the original's).

Layout of ``<out>/optimize/<part name>/``:

- ``iterations/<part name>_<k>/``: each run's folder (Parquet, run.json, the process report and its block table);
  ``iterations/<k>.<suffix>``: the program run in iteration k (0: a copy of the original);
- ``optimize.json``: every iteration so far (cycle time, peak force per tool, limits broken, the factors), written
  after each run, so a killed optimization leaves what it had;
- at the end the optimized program ``<program stem>_optimized<suffix>`` (same dialect, same lines; only F words),
  ``optimize_report.html`` (before and after per block, cycle time, the changed lines as a diff) and
  ``blocks_before_after.csv``.
"""
from __future__ import annotations

import functools
import json
import logging
import math
import re
import shutil
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import pandas as pd

from milling_twin.models.interpolator.definition import default_parameters
from milling_twin.models.interpolator.parser import Program
from milling_twin.orchestrator import atomic_files
from milling_twin.orchestrator.optimize import program_edit, schedule, spindle
from milling_twin.orchestrator.optimize.speed_map import simulate_speeds
from milling_twin.orchestrator.optimize.sub_blocks import (SplitProgram, SubBlockPlan, line_profiles, plan_sub_blocks,
                                                           split_lines, splittable_lines)
from milling_twin.orchestrator.optimize.spec import OptimizeSpec, read_optimize
from milling_twin.orchestrator.master import SimulationError
from milling_twin.orchestrator.part import checks
from milling_twin.orchestrator.part.blocks import descent_slopes, feed_lines
from milling_twin.orchestrator.scenario import ScenarioError, _Ctx

__all__ = ["Iteration", "OptimizeError", "OptimizeResult", "optimize"]

_log = logging.getLogger("milling_twin.optimize")
ITERATIONS = "iterations"
RECORDING_TABLES = ("recorded", "inputs", "compare", "alignment")
CONVERGED = 2e-3      # two runs that meet the limits and whose objective differs by less than this share: done


class OptimizeError(RuntimeError):
    """The optimization cannot go on: a run gave nothing to schedule from."""


@dataclass(frozen=True)
class Iteration:
    number: int
    program: Path
    run_dir: Path
    cycle_time: float                     # s: the process report's machining time
    peak_force: dict[int, float]          # N: largest resultant force per tool
    violations: tuple[str, ...]           # limits broken by more than the tolerance
    factors: dict[int, float]             # feed factor per program line (1: as originally programmed)
    force_scale: float                    # objective "force": the force limits' scale of this iteration
    wall_time: float                      # s: the run and its report
    sub_blocks: bool = False              # its program lines are those of the program with sub-blocks
    status: str = "completed"             # the run's: "completed", or how it ended ("failed: ...")

    @property
    def feasible(self) -> bool:
        return not self.violations


@dataclass(frozen=True)
class OptimizeResult:
    name: str
    folder: Path
    objective: str
    iterations: tuple[Iteration, ...]
    best: Iteration
    program: Path                          # the optimized program
    report: Path                           # optimize_report.html
    limits: dict[int, schedule.ToolLimits]
    wall_time: float
    stopped: str                           # why the iteration ended
    notes: tuple[str, ...] = field(default_factory=tuple)
    speeds: dict[int, spindle.SpeedChoice] = field(default_factory=dict)  # tools whose blocks chattered
    sub_blocks: SplitProgram | None = None   # the lines split (the iterations with ``sub_blocks``)

    @property
    def original(self) -> Iteration:
        return self.iterations[0]


class _OnceFilter(logging.Filter):
    """Messages that every iteration repeats (the program's notes: "M6: the tool change takes no time") pass once;
    the iteration's program file is the only difference between them."""

    def __init__(self, folder: Path) -> None:
        super().__init__()
        self.pattern = re.compile(re.escape(str(folder / ITERATIONS)) + r"/\d+")
        self.seen: set[str] = set()

    def filter(self, record: logging.LogRecord) -> bool:
        key = self.pattern.sub("<iteration>", record.getMessage())
        if key in self.seen:
            return False
        self.seen.add(key)
        return True


@contextmanager
def _each_message_once(folder: Path) -> Iterator[None]:
    once = _OnceFilter(folder)
    # the handlers (the command's) and the master's logger (the FMUs' messages: also without a handler set up)
    targets = [*logging.getLogger().handlers, logging.getLogger("milling_twin.orchestrator.master")]
    for target in targets:
        target.addFilter(once)
    try:
        yield
    finally:
        for target in targets:
            target.removeFilter(once)


def _part_document(path: Path) -> tuple[_Ctx, dict[str, Any]]:
    ctx = _Ctx(path)
    _, doc = ctx.document("scenario")
    if "part" not in doc:
        ctx.fail("[part]", "missing: the optimizer takes a whole-part scenario (a [part] table, docs/part.md)")
    return ctx, doc


def _parser(part) -> Callable[[str], Program]:
    """The part's program text as the Interpolator reads it (orchestrator/part/checks.py)."""
    return functools.partial(checks.parse_text, file=str(part.program), dialect=part.dialect, tools=part.tools,
                             machine=part.machine)


def tool_numbers(part) -> Callable[[int], int]:
    """The cutting tool of a block's tool number: with one cutting tool, that tool (also for T0, a program that
    selects none, as the process report takes it); with several, the number itself."""
    cutting = part.cutting_tools
    if len(cutting) == 1:
        only = cutting[0].tool.number
        return lambda number: only
    return int


def _peak_forces(runs: Mapping[int, schedule.LineRun]) -> dict[int, float]:
    peaks: dict[int, float] = {}
    for run in runs.values():
        if run.cuts:
            peaks[run.tool] = max(peaks.get(run.tool, 0.0), run.metrics["force"])
    return peaks


def _resolved_limits(spec: OptimizeSpec, part, original: Mapping[int, schedule.LineRun],
                     feeds: Mapping[int, float]) -> dict[int, schedule.ToolLimits]:
    """Each cutting tool's limits as numbers: the force default the original's largest, fz max twice the
    program's largest, the feed the Interpolator's max_feed."""
    machine_feed = float(part.machine.get("max_feed", default_parameters()["max_feed"]))
    peaks = _peak_forces(original)
    out: dict[int, schedule.ToolLimits] = {}
    for cut in part.cutting_tools:
        number, flutes = cut.tool.number, cut.tool.flutes
        per_tooth = [feeds[line] / (flutes * run.spindle / (2 * math.pi)) for line, run in original.items()
                     if run.tool == number and run.cuts and run.spindle > 0]
        out[number] = schedule.tool_limits(spec.for_tool(number), flutes, peaks.get(number, 0.0),
                                           max(per_tooth, default=0.0), machine_feed)
    return out


@dataclass(frozen=True)
class _Base:
    """The program the feeds are scheduled on: the original, or the original with its sub-blocks."""
    text: str
    feeds: dict[int, float]            # each feed-move line's programmed feed (m/s)
    plunges: frozenset[int]            # lines that cut descending more steeply than plunge_slope
    tools: dict[int, int]              # each feed-move line's tool number (as the program selects it)
    split: SplitProgram | None = None

    @classmethod
    def of(cls, text: str, parse: Callable[[str], Program], plunge_slope: float,
           split: SplitProgram | None = None) -> "_Base":
        program = parse(text)
        moving = feed_lines(program)
        feeds = {line: max(m.feed for m in moves) for line, moves in moving.items()}
        steep = frozenset(line for line, slope in descent_slopes(program).items() if slope > plunge_slope)
        return cls(text, feeds, steep, {line: moves[0].tool for line, moves in moving.items()}, split)

    def origin(self, line: int) -> int:
        """The original program's line of one of this program's lines."""
        return line if self.split is None else self.split.origin[line]


def _plan_sub_blocks(spec: OptimizeSpec, part, base: _Base, parse: Callable[[str], Program], run_dir: Path,
                     tool_of: Callable[[int], int]) -> dict[int, SubBlockPlan]:
    """The straight lines of the original run whose force changes along them (not plunges, not in air)."""
    from milling_twin.orchestrator.results import load_results

    program = parse(base.text)
    candidates = set(splittable_lines(program, base.text, str(part.program))) - base.plunges
    diameters = {cut.tool.number: cut.tool.diameter for cut in part.cutting_tools}
    frame = load_results(run_dir)
    profiles = line_profiles(frame, program, candidates, lambda tool: diameters.get(tool_of(tool)))
    return plan_sub_blocks(profiles, spec.sub_block_length)


def optimize(part_file: str | Path, *, fmu_dir: str | Path, out: str | Path = "runs", objective: str | None = None,
             max_iterations: int | None = None, sub_blocks: bool | None = None, workers: int | None = 0,
             progress: bool = False,
             echo: Callable[[str], None] | None = None) -> OptimizeResult:
    """Optimize the feeds of a whole-part scenario's program (see the module docstring); ``workers``: the study
    layer's for a chattering tool's simulated stability map (0: in this process; None: the machine's cores)."""
    from milling_twin.api import simulate
    from milling_twin.orchestrator.optimize.report import write_optimize_report
    from milling_twin.orchestrator.results import RunFolder
    from milling_twin.orchestrator.safe_names import check_name
    from milling_twin.orchestrator.scenario import load_scenario

    t_start = time.perf_counter()
    say = echo or (lambda text: _log.info(text))
    part_file = Path(part_file)
    ctx, doc = _part_document(part_file)
    spec = read_optimize(ctx, doc.get("optimize"))
    if objective is not None:
        spec = replace(spec, objective=objective)
    if max_iterations is not None:
        spec = replace(spec, max_iterations=max_iterations)
    if sub_blocks is not None:
        spec = replace(spec, sub_blocks=sub_blocks)
    scenario0 = load_scenario(part_file, fmu_dir, document=doc)
    part = scenario0.part
    name = scenario0.name
    check_name(name, f"{part_file}: [scenario].name")
    folder = (Path(out) / "optimize" / name).resolve()
    parse = _parser(part)
    tool_of = tool_numbers(part)
    original_text = program_edit.read_program(part.program)
    base = _Base.of(original_text, parse, spec.plunge_slope)
    original_feeds = base.feeds
    iterations: list[Iteration] = []
    history: list[dict[int, schedule.LineRun]] = []
    limits: dict[int, schedule.ToolLimits] = {}
    original_runs: dict[int, schedule.LineRun] = {}

    with RunFolder.claim(folder, what="optimization"), _each_message_once(folder):
        runs_dir = folder / ITERATIONS
        runs_dir.mkdir(parents=True, exist_ok=True)

        chosen: dict[int, spindle.SpeedChoice] = {}

        def record() -> None:
            atomic_files.write_text(folder / "optimize.json", json.dumps(_document(
                part_file, spec, limits, iterations, time.perf_counter() - t_start, chosen, base.split), indent=1))

        def run(k: int, text: str, factors: dict[int, float], scale: float) -> Iteration:
            program_path = runs_dir / f"{k}{part.program.suffix}"
            atomic_files.write_text(program_path, text, encoding="latin-1")
            # the part alone: a recording (and what reads it) belongs to the original program's run on the machine;
            # the stop time is each program's own machining time (the expansion's default)
            edited = {key: value for key, value in doc.items() if key not in RECORDING_TABLES}
            edited["scenario"] = {key: value for key, value in doc.get("scenario", {}).items() if key != "stop_time"}
            edited["scenario"]["name"] = f"{name}_{k}"
            edited["part"] = {**doc["part"], "program": str(program_path)}
            scenario = load_scenario(part_file, fmu_dir, document=edited)
            t0 = time.perf_counter()
            try:
                results = simulate(scenario, out=runs_dir, progress=progress)
                status, process, run_dir = results.status, results.process_report, Path(results.run_dir)
            except SimulationError as exc:  # an FMU refused a value (a vibration out of its range, say)
                status, process, run_dir = f"failed: {exc}", exc.process_report, Path(exc.run_dir or runs_dir)
            if process is None:  # no rows: nothing to schedule from
                raise OptimizeError(f"iteration {k} ({program_path}): the run gave no rows ({status}); "
                                    f"the iterations before are in {folder / 'optimize.json'}")
            blocks = pd.read_parquet(process.blocks_parquet)
            runs = schedule.line_runs(blocks, base.feeds, list(base.feeds), tool_of)
            history.append(runs)
            if not original_runs:
                original_runs.update(runs)
            if not limits:
                limits.update(_resolved_limits(spec, part, runs, original_feeds))
            # the limits themselves (objective force: the scaled force limit only steers the schedule; the run is
            # judged by its largest force and its cycle time); chatter against the original line's
            reference = {line: original_runs[base.origin(line)] for line in runs if base.origin(line) in original_runs}
            broken = schedule.violations(runs, limits.get, spec.tolerance, reference)
            if status != "completed":  # an FMU ended or failed the run (a tool displacement out of range, say)
                broken.append(f"the run did not complete: {status}")
            reference = _reference_time(iterations)
            if spec.objective == "force" and reference is not None and \
                    process.machining_time > reference * (1 + spec.tolerance):
                broken.append(f"cycle time {process.machining_time:.4g} s longer than the "
                              f"original's {reference:.4g} s")
            it = Iteration(k, program_path, run_dir, process.machining_time,
                           _peak_forces(runs), tuple(broken), dict(factors), scale, time.perf_counter() - t0,
                           base.split is not None, status)
            iterations.append(it)
            record()
            peak = max(it.peak_force.values(), default=0.0)
            say(f"iteration {k}: cycle {it.cycle_time:.2f} s, peak force {peak:.4g} N, "
                f"{'every limit holds' if it.feasible else f'{len(broken)} limits broken'} ({it.wall_time:.1f} s)")
            return it

        run(0, original_text, {line: 1.0 for line in base.feeds}, 1.0)
        stopped = f"{spec.max_iterations} iterations"
        scale = 1.0

        def speed_map(cut, speeds, depth, per_tooth, label):  # a chattering tool's simulated map: a study
            say(f"T{cut.tool.number} chatters: its simulated stability map at {depth * 1e3:.3g} mm over "
                f"{len(speeds)} speeds")
            return simulate_speeds(folder / "speeds", part, cut, speeds, depth, per_tooth, Path(fmu_dir).resolve(),
                                   workers, label)
        speeds = spindle.choose_speeds(part, pd.read_parquet(iterations[0].run_dir / "blocks.parquet"),
                                       spec.speed_range, spec.stability_margin, tool_of,
                                       speed_map if spec.speed_from == "simulated" else None)
        ratios = {tool: choice.ratio for tool, choice in speeds.items() if choice.ratio != 1.0}

        def at_new_speeds(program: _Base) -> program_edit.EditedProgram:
            """``program`` with the tools' new S words and their feeds in proportion (the same chip)."""
            return program_edit.rewrite_feeds(program.text, {line: ratios.get(tool_of(program.tools[line]), 1.0)
                                                             for line in program.feeds},
                                              parse, str(part.program), part.dialect, ratios)
        if ratios:
            try:  # checked on the original, so that a refusal names the program's own lines
                at_new_speeds(base)
            except program_edit.ProgramEditError as exc:  # feeds per revolution (G95) follow S: not this way
                speeds = {tool: replace(c, chosen=c.programmed, note=f"the speed of a stable pocket "
                                        f"({c.chosen:.0f} rpm) cannot be written into this program ({exc}): S kept")
                          if tool in ratios else c for tool, c in speeds.items()}
                ratios = {}
        chosen.update(speeds)
        if iterations[0].status != "completed" and not ratios:
            raise OptimizeError(f"the original program's run did not complete ({iterations[0].status}) and no "
                                f"chattering tool's speed could change that; its blocks so far are in "
                                f"{iterations[0].run_dir}")
        plans = _plan_sub_blocks(spec, part, base, parse, iterations[0].run_dir, tool_of) if spec.sub_blocks else {}
        first = 1
        if plans:
            split = split_lines(original_text, plans, parse, str(part.program), part.dialect)
            base = _Base.of(split.text, parse, spec.plunge_slope, split)
            say(f"sub-blocks: {len(plans)} lines split into {len(split.parts)} sub-blocks where their engagement "
                f"changes")
        if ratios or plans:
            # a chattering tool at the speed of its stable pocket, its feeds in proportion (the same chip), and the
            # lines split into their sub-blocks: the feed schedule starts again from this run (the forces of the old
            # speed are no model for the new one; the sub-blocks have their own)
            edited = at_new_speeds(base)
            ratios = edited.speeds
            first_run = run(1, edited.text, edited.factors, scale)
            history[:] = history[1:]
            first = 2 if first_run.status == "completed" else spec.max_iterations + 1
            if first_run.status != "completed":
                stopped = f"iteration 1's run did not complete ({first_run.status})"
        for k in range(first, spec.max_iterations + 1):
            if spec.objective == "force":
                scale = schedule.scale_for_time(history, base.feeds, limits.get, spec.air_moves,
                                                iterations[-1].cycle_time, _reference_time(iterations),
                                                base.plunges)
            factors = schedule.next_factors(history, base.feeds, limits.get, spec.air_moves, scale, base.plunges)
            last = iterations[-1]
            if all(abs(factors[line] - last.factors.get(line, 1.0)) <= 1e-3 * last.factors.get(line, 1.0)
                   for line in factors) and last.feasible:
                stopped = "converged: the feeds no longer change"
                break
            edited = program_edit.rewrite_feeds(base.text, factors, parse, str(part.program), part.dialect,
                                                ratios)
            it = run(k, edited.text, edited.factors, scale)
            if it.status != "completed":  # its blocks end where it failed: no schedule for the lines after
                stopped = f"iteration {k}'s run did not complete ({it.status})"
                break
            if it.feasible and last.feasible and abs(_objective(it, spec) / _objective(last, spec) - 1) < CONVERGED:
                stopped = "converged: two runs in a row meet the limits with the same objective"
                break
        best = _best(iterations, spec)
        optimized = folder / f"{part.program.stem}_optimized{part.program.suffix}"
        shutil.copyfile(best.program, optimized)
        report = write_optimize_report(folder, part, spec, limits, iterations, best, original_text,
                                       program_edit.read_program(best.program), stopped, original_feeds, tool_of,
                                       speeds if best.number > 0 else {},
                                       (base.split, base.feeds) if best.sub_blocks else None)
        record()
    notes = [f"the runs leave out the part file's {', '.join(f'[{t}]' for t in RECORDING_TABLES if t in doc)}: "
             f"a recording belongs to the original program's run"] if any(t in doc for t in RECORDING_TABLES) else []
    if best.number == 0:
        notes.append("no iteration met every limit and improved on the original: the optimized program is the "
                     "original")
    notes += [f"T{tool}: {choice.note}" for tool, choice in speeds.items() if choice.note]
    return OptimizeResult(name, folder, spec.objective, tuple(iterations), best, optimized, report, limits,
                          time.perf_counter() - t_start, stopped, tuple(notes), speeds, base.split)


def _reference_time(iterations: list[Iteration]) -> float | None:
    """The cycle time the objective "force" keeps: the original's, or where the original's run failed (a tool's
    vibration out of range) that of the first run that completed (the speed moved to a stable pocket)."""
    return next((it.cycle_time for it in iterations if it.status == "completed"), None)


def _objective(it: Iteration, spec: OptimizeSpec) -> float:
    """Smaller is better: the cycle time, or the largest peak force (objective "force")."""
    return it.cycle_time if spec.objective == "time" else max(it.peak_force.values(), default=0.0)


def _best(iterations: list[Iteration], spec: OptimizeSpec) -> Iteration:
    feasible = [it for it in iterations if it.feasible]
    return min(feasible, key=lambda it: (_objective(it, spec), it.number)) if feasible else iterations[0]


def _document(part_file: Path, spec: OptimizeSpec, limits: Mapping[int, schedule.ToolLimits],
              iterations: list[Iteration], wall_time: float, speeds: Mapping[int, spindle.SpeedChoice],
              split: SplitProgram | None) -> dict[str, Any]:
    def finite(x: float) -> float | None:
        return x if math.isfinite(x) else None
    return {
        "part": str(part_file.resolve()), "objective": spec.objective, "tolerance": spec.tolerance,
        "air_moves": spec.air_moves, "wall_time": wall_time,
        "limits": {str(tool): {**lim.process, "feed_per_tooth_min": lim.feed_per_tooth_min,
                               "feed_per_tooth_max": finite(lim.feed_per_tooth_max), "feed": lim.feed,
                               "flutes": lim.flutes} for tool, lim in limits.items()},
        "spindle_speeds": {str(tool): {"programmed": c.programmed, "chosen": c.chosen,
                                       "deepest_chattering_cut": c.depth,
                                       "limit_programmed": c.limit_programmed, "limit_chosen": c.limit_chosen,
                                       "source": c.source, "dynamic_chip_programmed": finite(c.chip_programmed),
                                       "dynamic_chip_chosen": finite(c.chip_chosen),
                                       "stable_in_simulated_map": c.stable_chosen,
                                       "study": str(c.study) if c.study else None,
                                       "note": c.note} for tool, c in speeds.items()},
        "units": {"cycle_time": "s", "peak_force": "N", "force": "N", "torque": "N.m", "power": "W",
                  "deflection": "m", "feed_per_tooth_min": "m", "feed_per_tooth_max": "m", "feed": "m/s",
                  "programmed": "rpm", "chosen": "rpm", "deepest_chattering_cut": "m", "limit_programmed": "m",
                  "limit_chosen": "m", "dynamic_chip_programmed": "1 (x the feed per tooth)",
                  "dynamic_chip_chosen": "1 (x the feed per tooth)"},
        # the lines of the program with sub-blocks (the iterations with "sub_blocks": their factors' lines): each
        # one's line in the original, and for the parts of a split line which part of how many
        "sub_blocks": {str(line): {"line": split.origin[line], **({"part": part[0], "of": part[1]}
                                                                   if (part := split.parts.get(line)) else {})}
                       for line in sorted(split.origin)} if split else {},
        "iterations": [{"iteration": it.number, "program": str(it.program), "run_dir": str(it.run_dir),
                        "sub_blocks": it.sub_blocks,
                        "cycle_time": it.cycle_time, "peak_force": {str(k): v for k, v in it.peak_force.items()},
                        "feasible": it.feasible, "violations": list(it.violations), "force_scale": it.force_scale,
                        "status": it.status,
                        "wall_time": it.wall_time, "factors": {str(k): v for k, v in it.factors.items()}}
                       for it in iterations]}
