"""The ``milling-twin`` command (also ``python -m milling_twin``): every subcommand, one exit-code table.

The parser is built here, without importing the subcommands' modules (``--help`` needs neither casadi,
matplotlib nor torch); each subcommand names its handler as ``module:function``, imported when it runs.
Handlers take the parsed arguments and return an exit code, or raise: :data:`EXIT_CODES` maps what they
raise to the exit code and a one-line ``error: ...`` message (with ``--log-level debug``, the traceback).
"""
from __future__ import annotations

import argparse
import importlib
import logging
import math
import re
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

from milling_twin import __version__
from milling_twin.api import FMU_DIR_ENV, default_fmu_dir

LOG_LEVELS = ("debug", "info", "warning", "error")


@dataclass(frozen=True)
class ExitCode:
    """Exceptions of class ``module.name`` (and subclasses) end a command with ``code``."""

    module: str
    name: str
    code: int
    meaning: str

    def matches(self, exc: BaseException) -> bool:
        module = sys.modules.get(self.module)  # an exception of a module never imported cannot have been raised
        cls = getattr(module, self.name, None) if module is not None else None
        return isinstance(cls, type) and isinstance(exc, cls)


# The one table of exit codes for every subcommand (docs/orchestrator.md lists it). First match wins, so the
# more specific classes stand first. 0 is success; 3 (a result rejected) is returned, not raised.
EXIT_CODES: tuple[ExitCode, ...] = (
    ExitCode("builtins", "KeyboardInterrupt", 130,
             "interrupted (Ctrl-C, SIGTERM or SIGHUP during a run); results so far are kept"),
    ExitCode("milling_twin.cli", "UsageError", 2, "a command-line value is invalid"),
    ExitCode("milling_twin.orchestrator.scenario", "ScenarioError", 2,
             "invalid scenario, parameter set or --set override"),
    ExitCode("milling_twin.orchestrator.recorded", "RecordedDataError", 2, "invalid recorded data"),
    ExitCode("milling_twin.models.units", "UnitError", 2, "unknown unit, or a unit of another dimension"),
    ExitCode("milling_twin.orchestrator.calibrate.errors", "CalibrationSpecError", 2, "invalid calibration spec"),
    ExitCode("milling_twin.orchestrator.study.spec", "StudyError", 2, "invalid study file"),
    ExitCode("milling_twin.datasets", "DataMissing", 2, "a data set is not where it was looked for"),
    ExitCode("milling_twin.orchestrator.fastpath", "FastPathUnavailable", 2, "--path fast cannot run this scenario"),
    ExitCode("milling_twin.orchestrator.align.errors", "AlignmentError", 2,
             "invalid alignment input, or data that cannot be aligned"),
    ExitCode("builtins", "FileNotFoundError", 2, "an input file does not exist"),
    ExitCode("milling_twin.orchestrator.master", "SimulationError", 1, "an FMU call failed; results so far are kept"),
    ExitCode("milling_twin.orchestrator.calibrate.errors", "CalibrationError", 1, "the calibration failed"),
    ExitCode("milling_twin.orchestrator.optimize.run", "OptimizeError", 1,
             "the optimization could not go on; the iterations so far are kept"),
    ExitCode("milling_twin.orchestrator.results", "RunFolderBusy", 1,
             "the run folder is in use by another run (see run --if-busy)"),
    ExitCode("milling_twin.orchestrator.results", "MixedRunError", 1, "a run folder holds chunks of two runs"),
    ExitCode("builtins", "OSError", 1, "a file could not be read or written"),
    ExitCode("builtins", "ValueError", 2, "an input file holds an invalid value"),
)
REJECTED = 3  # returned by `align spatial` when the registration is rejected (F > k): no G-code


class UsageError(ValueError):
    """A command-line value the parser could not check (an --set override, say)."""


# --- option helpers ---------------------------------------------------------------------------------------

_NUMBER = re.compile(r"^\s*([+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)\s*(\S.*)?$")


def parse_override(text: str) -> tuple[str, object]:
    """``instance.variable=value[unit]`` -> (``"instance.variable"``, value): a number (with its unit,
    ``{"value": 0.25, "unit": "kW"}``, converted to SI by the scenario), ``true``/``false``, or a string."""
    key, sep, raw = text.partition("=")
    key = key.strip()
    instance, dot, variable = key.partition(".")
    if not sep or not dot or not instance or not variable:
        raise UsageError(f"--set {text!r}: expected INSTANCE.VARIABLE=VALUE[UNIT], e.g. power.P_idle=0.25kW")
    match = _NUMBER.match(raw)
    if match:
        value = float(match.group(1))
        if not math.isfinite(value):
            raise UsageError(f"--set {key}: {raw!r} is not a finite number")
        if match.group(2):
            return key, {"value": value, "unit": match.group(2).strip()}
        # a whole number stays one, as in TOML: an Integer/Int32 parameter (n_flutes) takes it, a Real one too
        return key, int(match.group(1)) if re.fullmatch(r"\s*[+-]?\d+\s*", match.group(1)) else value
    if raw.strip().lower().lstrip("+-") in ("nan", "inf", "infinity"):
        raise UsageError(f"--set {key}: {raw.strip()!r} is not a finite number")
    if raw.strip().lower() in ("true", "false"):
        return key, raw.strip().lower() == "true"
    return key, raw


def overrides_of(args: argparse.Namespace) -> dict[str, object]:
    return dict(parse_override(text) for text in args.set or ())


def _add_fmu_dir(p: argparse.ArgumentParser) -> None:
    p.add_argument("--fmu-dir", type=Path, default=default_fmu_dir(),
                   help=f"folder of the built FMUs (default: ${FMU_DIR_ENV}, else build/fmus when it exists "
                        "(`make build` makes them), else the FMUs installed with the package)")


def _add_set(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", action="append", metavar="INSTANCE.VARIABLE=VALUE[UNIT]",
                   help="change a parameter or constant input, e.g. --set power.P_idle=0.25kW (repeatable; "
                        "a number without unit is SI)")


def _columns(text: str) -> list[str]:
    cols = [c.strip() for c in text.split(",") if c.strip()]
    if len(cols) != 3:
        raise argparse.ArgumentTypeError(f"give three comma-separated columns (x,y,z), got {text!r}")
    return cols


# --- the subcommands ----------------------------------------------------------------------------------------

def _run(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", type=Path, help="scenario TOML file, or an SSP archive (.ssp, e.g. from export-ssp)")
    _add_fmu_dir(p)
    p.add_argument("--out", type=Path, default=Path("runs"), help="results go to OUT/<scenario name>/ (default: runs)")
    _add_set(p)
    p.add_argument("--parameter-set", type=Path, action="append", default=[], metavar="FILE",
                   help="a parameter set (TOML, e.g. written by calibrate) applied after the scenario's own "
                        "(repeatable)")
    p.add_argument("--recording", type=Path, default=None, metavar="CSV",
                   help="another recording of the same machine and logger, read instead of the scenario's "
                        "[recorded].file (same columns, channels and checks)")
    p.add_argument("--path", choices=("auto", "fast", "python"), default="auto",
                   help="stepping loop: fast (compiled), python (reference), or auto (fast when its library is "
                        "found and the scenario is supported; default)")
    p.add_argument("--fmi-logging", action="store_true",
                   help="log every FMI call and every FMU message (runs the python stepping loop)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--if-busy", choices=("refuse", "wait", "new"), default="refuse",
                   help="when another run is writing into OUT/<scenario name>/: refuse (default: exit 1, nothing "
                        "written), wait until it ends, or write to a new folder OUT/<scenario name>-2/ (-3, ...)")


def _calibrate(p: argparse.ArgumentParser) -> None:
    p.add_argument("spec", type=Path, help="calibration spec TOML file (format: docs/calibration.md)")
    _add_fmu_dir(p)
    p.add_argument("--out", type=Path, default=Path("runs"),
                   help="report, parameter set and runs go to OUT/calibration/<name>/ (default: runs)")
    p.add_argument("--data", type=Path, default=None,
                   help="the recordings' folder: slot-milling recordings (kind slot_forces; default "
                        "$MILLING_TWIN_SLOT_DATA or ../shared/data/slot_milling_forces) or the runs (kind runs; "
                        "default the spec's [runs].folder)")
    _add_set(p)
    p.add_argument("--write-set", type=Path, metavar="PATH",
                   help="also publish the calibrated parameter set here (e.g. the spec's parameter_set, to "
                        "update the committed one); without it only OUT is written")
    _add_workers(p, "a fit through the FMUs runs its starts and finite-difference columns on N local worker "
                    "processes, with the serial result (0: serially; default: the spec's [solver] workers)",
                 "the same on an existing dask cluster: its scheduler's address (tcp://host:8786) or file")
    p.add_argument("--no-progress", action="store_true", help="no progress bars")


def _align_temporal(t: argparse.ArgumentParser) -> None:
    t.add_argument("--recorded", required=True, type=Path, help="recording (CSV)")
    t.add_argument("--columns", required=True, type=_columns, help="recorded x,y,z position columns")
    t.add_argument("--unit", default="mm", help="unit of the recorded positions (default mm)")
    g = t.add_mutually_exclusive_group(required=True)
    g.add_argument("--sample-period", type=float, help="recorded rows are this many s apart")
    g.add_argument("--time-column", help="recorded time column")
    t.add_argument("--time-unit", default="s")
    s = t.add_mutually_exclusive_group(required=True)
    s.add_argument("--results", type=Path, help="run folder of the simulation")
    s.add_argument("--simulated", type=Path, help="simulated positions (CSV, column 'time')")
    t.add_argument("--sim-columns", required=True, type=_columns,
                   help="simulated x,y,z columns (results: instance.variable)")
    t.add_argument("--sim-unit", default="m", help="unit of --simulated columns (default m)")
    t.add_argument("--output-delay", type=float, default=0.0,
                   help="s to shift results back (docs/alignment.md)")
    t.add_argument("--method", choices=("multiscale", "patent", "dtw"), default="multiscale")
    t.add_argument("--out", type=Path, required=True, help="time map CSV to write")
    t.add_argument("--min-confidence", type=float, default=0.3,
                   help="median confidence below which the alignment (each segment of it) is reported as failed "
                        "(default 0.3, orchestrator.align.segments.DEFAULT_MIN_CONFIDENCE)")
    t.add_argument("--plot", type=Path, help="figure (PNG) to write")
    t.add_argument("--progress", action="store_true")


def _align_spatial(p: argparse.ArgumentParser) -> None:
    p.add_argument("--probes", required=True, type=Path, help="CSV: x, y, z, thickness")
    p.add_argument("--design", required=True, type=Path, help="CSV: x, y, z (design target S3)")
    p.add_argument("--design-thickness", required=True, type=float)
    p.add_argument("--threshold", required=True, type=float, help="k: largest accepted F")
    p.add_argument("--g54", required=True, type=float, nargs=3, metavar=("X", "Y", "Z"))
    p.add_argument("--register", type=int, default=2, help="2..6 = G55..G59 (default 2)")
    p.add_argument("--geometry", choices=("cylinder", "plane"), default="cylinder")
    p.add_argument("--outward", choices=("x", "y", "z"), default="x", help="plane: axis the wall faces")
    p.add_argument("--centre", choices=("centroid", "registration"), default=None,
                   help="default: centroid for cylinder, registration for plane")
    p.add_argument("--plot", type=Path)
    p.add_argument("--out", type=Path, help="result JSON to write")


def _validate_slot_milling(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", type=Path, help="folder of the recordings (default: $MILLING_TWIN_SLOT_DATA or "
                                             "../shared/data/slot_milling_forces)")
    p.add_argument("--scenario", type=Path, default=Path("scenarios/slot_milling.toml"))
    _add_fmu_dir(p)
    p.add_argument("--out", type=Path, default=Path("runs"),
                   help="results go to OUT/<scenario file name>/ (default: runs)")
    p.add_argument("--finetuned", type=Path, help="ForceNet scenarios: folder of the left-out fine-tuned weights "
                                                  "(milling-twin train forcenet-finetune)")


def _validate_chatter(p: argparse.ArgumentParser) -> None:
    p.add_argument("--speeds", type=float, nargs="+", default=None, help="spindle speeds, rpm")
    p.add_argument("--iterations", type=int, default=8, help="bisection steps per speed")
    p.add_argument("--scenario", type=Path, default=Path("scenarios/chatter.toml"))
    _add_fmu_dir(p)
    p.add_argument("--out", type=Path, default=Path("runs"))
    p.add_argument("--figure", type=Path, help="also write the plot here (e.g. for docs)")


def _validate_forcenet_figure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--runs", type=Path, default=Path("runs"),
                   help="where `validate slot-milling` wrote its results (default: runs)")
    _add_fmu_dir(p)
    p.add_argument("--out", type=Path, default=Path("scenarios/figures/forcenet_slot_milling.png"))


def _lobes(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", type=Path, help="scenario with a CuttingForce instance 'force' and a ToolVibration "
                                               "instance 'vibration' (e.g. scenarios/chatter.toml)")
    _add_fmu_dir(p)
    _add_set(p)
    p.add_argument("--speeds", type=float, nargs=2, default=(3000.0, 30000.0), metavar=("MIN", "MAX"),
                   help="spindle speed range, rpm (default 3000 30000)")
    p.add_argument("--points", type=int, default=500, help="speeds in the range (default 500)")
    p.add_argument("--out", type=Path, default=Path("runs/lobes.png"), help="plot (PNG; default runs/lobes.png)")
    p.add_argument("--csv", type=Path, help="also write speed [rpm], limiting depth [mm] as CSV")


def _train_forcenet(p: argparse.ArgumentParser) -> None:
    p.add_argument("--quick", action="store_true", help="a short run (tests)")
    p.add_argument("--out", type=Path, default=None,
                   help="weights file (default: the FMU's fmus/forcenet/resources/weights.bin)")
    p.add_argument("--report", type=Path, default=Path("runs/forcenet/train_report.json"))
    p.add_argument("--header-only", action="store_true",
                   help="only regenerate fmus/forcenet/default_weights.h from resources/weights.bin")


def _train_forcenet_finetune(p: argparse.ArgumentParser) -> None:
    p.add_argument("--data", type=Path, help="slot-milling recordings (default: $MILLING_TWIN_SLOT_DATA or "
                                             "../shared/data/slot_milling_forces)")
    p.add_argument("--out", type=Path, default=Path("runs/forcenet_finetune"))


def _train_rbf(p: argparse.ArgumentParser) -> None:
    p.add_argument("program", type=Path, help="part program with the NURBS block(s) to train on")
    p.add_argument("--param", action="append", default=[], help="interpolator parameter name=value (SI)")
    p.add_argument("--out", type=Path, required=True, help="weights file (TOML) to write")
    p.add_argument("--epochs", type=int, default=None, help="gradient-descent epochs")


def _add_workers(p: argparse.ArgumentParser, workers_help: str, scheduler_help: str) -> None:
    """--workers N or --scheduler ADDR|FILE (one of them): where the parallel work runs."""
    where = p.add_mutually_exclusive_group()
    where.add_argument("--workers", type=_workers, default=None, metavar="N", help=workers_help)
    where.add_argument("--scheduler", default=None, metavar="ADDR|FILE", help=scheduler_help)


def _workers(text: str) -> int:
    try:
        n = int(text)
    except ValueError:
        n = -1
    if n < 0:
        raise argparse.ArgumentTypeError(f"expected 0 (serial, in this process) or a number of workers, got {text!r}")
    return n


def _sweep(p: argparse.ArgumentParser) -> None:
    p.add_argument("study", type=Path, help="study TOML file ([study]: base scenario, cases, reductions)")
    _add_fmu_dir(p)
    p.add_argument("--out", type=Path, default=Path("runs"),
                   help="the study goes to OUT/<study name>/: summary.parquet, summary/, cases/ (default: runs)")
    _add_workers(p, "N local worker processes (0: serially in this process); default: an embedded dask cluster with "
                    "one worker per core",
                 "an existing dask cluster: its scheduler's address (tcp://host:8786) or scheduler file")
    p.add_argument("--resume", action="store_true",
                   help="skip the cases the summary has as ok (a killed or failed study goes on)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _optimize(p: argparse.ArgumentParser) -> None:
    p.add_argument("part", type=Path, help="whole-part scenario (TOML with [part]; its [optimize] holds the limits)")
    _add_fmu_dir(p)
    p.add_argument("--out", type=Path, default=Path("runs"),
                   help="the optimization goes to OUT/optimize/<part name>/ (default: runs)")
    p.add_argument("--objective", choices=("time", "force"), default=None,
                   help="time: the shortest cycle within the limits; force: the original cycle time with the lowest "
                        "peak force (default: [optimize].objective, else time)")
    p.add_argument("--max-iterations", type=int, default=None,
                   help="re-simulations after the original run (default: [optimize].max_iterations, else 6)")
    p.add_argument("--no-sub-blocks", action="store_true",
                   help="one feed per program line: no line split into sub-blocks (default: "
                        "[optimize].sub_blocks, else split where the engagement changes along a line)")
    p.add_argument("--workers", type=int, default=0,
                   help="the study layer's workers for a chattering tool's simulated stability map (default 0: in "
                        "this process, a map takes seconds)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")


def _info(p: argparse.ArgumentParser) -> None:
    p.add_argument("fmu", type=Path, help="an .fmu file (or a model name found in --fmu-dir, e.g. SpindlePower)")
    _add_fmu_dir(p)


def _reconstruct(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", type=Path, help="recorded run (CSV with the UMich columns)")
    p.add_argument("-o", "--output", type=Path, required=True,
                   help="part program to write when the recording is one consistent pass; otherwise a folder "
                        "that gets one program per consistent segment (seg_NNN.nc) and the index segments.csv "
                        "(rows, times, program, start position, duration recorded and simulated, why a segment "
                        "has no program)")


def _program(p: argparse.ArgumentParser) -> None:
    p.add_argument("program", type=Path, help="part program (G-code) as a CAM post-processor writes it")
    p.add_argument("--dialect", choices=("fanuc", "linuxcnc", "sinumerik"), default="fanuc",
                   help="G-code dialect (the Interpolator's dialect parameter; default fanuc)")
    p.add_argument("--tool-table", type=Path, help="tool table in LinuxCNC's format (the tool_table parameter)")
    p.add_argument("--param", action="append", metavar="NAME=VALUE",
                   help="an Interpolator parameter in SI units (e.g. acceleration=2, max_feed=0.5); repeatable")


def _expand(p: argparse.ArgumentParser) -> None:
    p.add_argument("part", type=Path, help="whole-part scenario (TOML with a [part] table, docs/part.md)")
    p.add_argument("-o", "--output", type=Path, default=None,
                   help="explicit scenario (TOML) to write, paths relative to it; default: stdout, paths relative "
                        "to the current directory")
    _add_fmu_dir(p)


def _export_ssp(p: argparse.ArgumentParser) -> None:
    p.add_argument("scenario", type=Path, help="scenario TOML file (a whole-part one is exported as it expands)")
    p.add_argument("-o", "--output", type=Path, required=True, help="SSP archive to write (e.g. twin.ssp)")
    _add_fmu_dir(p)
    _add_set(p)
    p.add_argument("--parameter-set", type=Path, action="append", default=[], metavar="FILE",
                   help="a parameter set (TOML) applied after the scenario's own (repeatable)")


@dataclass(frozen=True)
class Subcommand:
    name: str
    help: str
    arguments: Callable[[argparse.ArgumentParser], None]
    handler: str  # "module:function", imported when the subcommand runs


@dataclass(frozen=True)
class Group:
    name: str
    help: str
    subcommands: tuple[Subcommand, ...]


COMMANDS: tuple[Subcommand | Group, ...] = (
    Subcommand("run", "run a scenario: co-simulate, write results and the comparison report", _run,
               "milling_twin.commands:run"),
    Subcommand("calibrate", "fit model parameters to recorded data (a calibration spec)", _calibrate,
               "milling_twin.commands:calibrate"),
    Subcommand("sweep", "run a study: many cases of a scenario (grid, list, sample, Monte Carlo) on dask workers, "
               "one summary row per case", _sweep, "milling_twin.orchestrator.study.cli:command"),
    Subcommand("optimize", "schedule a whole part's feeds block by block within force, torque, power and "
               "deflection limits, verified by re-simulation; writes the program (only F words changed) and a "
               "report", _optimize, "milling_twin.orchestrator.optimize.cli:command"),
    Group("align", "align recorded data with simulation in time or space", (
        Subcommand("temporal", "map every recorded sample to its simulated moment; writes the time map (CSV)",
                   _align_temporal, "milling_twin.orchestrator.align.cli:temporal"),
        Subcommand("spatial", "wall-thickness compensation by work-offset shift from probe and design points",
                   _align_spatial, "milling_twin.orchestrator.align.cli:spatial"))),
    Group("validate", "compare the models with measurements and analytic results", (
        Subcommand("slot-milling", "CuttingForce or ForceNet against the measured slot-milling forces",
                   _validate_slot_milling, "milling_twin.orchestrator.validation.slot_milling:command"),
        Subcommand("chatter", "simulated chatter onset against the analytic stability lobes", _validate_chatter,
                   "milling_twin.orchestrator.validation.chatter:command"),
        Subcommand("forcenet-figure", "the figure of ForceNet and CuttingForce against the slot-milling forces",
                   _validate_forcenet_figure, "milling_twin.training.force_net_figure:command"))),
    Subcommand("lobes", "analytic stability lobes of a scenario's tool, modes and cutting coefficients", _lobes,
               "milling_twin.orchestrator.validation.lobes:command"),
    Group("train", "train the learned model parts (torch for the force net: the 'train' extra)", (
        Subcommand("forcenet", "train the force net on the mechanistic model and install its weights",
                   _train_forcenet, "milling_twin.training.force_net:train_command"),
        Subcommand("forcenet-finetune", "leave-one-feed-out fine-tuning on the slot-milling recordings",
                   _train_forcenet_finetune, "milling_twin.training.force_net:finetune_command"),
        Subcommand("rbf", "train the interpolator's RBF parameter predictor on a NURBS program", _train_rbf,
                   "milling_twin.training.rbf:command"))),
    Subcommand("info", "an FMU's variables: causality, type, units and display units, start, range", _info,
               "milling_twin.orchestrator.fmu_info:command"),
    Subcommand("program", "read a part program as the Interpolator does: moves, machining time, tools, words not "
               "modelled, or the line it refuses", _program, "milling_twin.orchestrator.gcode.program_summary:command"),
    Subcommand("expand", "write a whole-part scenario ([part]) as the explicit scenario it runs: instances, "
               "parameters, connections, stepping", _expand, "milling_twin.orchestrator.part.expand:command"),
    Subcommand("export-ssp", "write a scenario as an SSP 1.0 archive (SSD, parameter sets, the FMUs) for other "
               "co-simulation tools; `run` takes the archive back", _export_ssp,
               "milling_twin.orchestrator.ssp.export:command"),
    Subcommand("reconstruct", "rebuild a part program (G-code) from a UMich recording, one per consistent segment",
               _reconstruct,
               "milling_twin.orchestrator.gcode.reconstruct:command"),
)


def exit_code_table() -> str:
    """The exit codes as a Markdown table (docs/orchestrator.md holds it verbatim; a test keeps it so)."""
    rows = ["| code | when | raised as |", "|---:|---|---|", "| 0 | done | |"]
    for e in sorted(EXIT_CODES, key=lambda e: (e.code, EXIT_CODES.index(e))):
        rows.append(f"| {e.code} | {e.meaning} | `{e.name}` |")
    rows.insert(-1, f"| {REJECTED} | a result was rejected (align spatial: F > k, no G-code is printed) | (returned) |")
    return "\n".join(rows)


def _exit_code_epilog() -> str:
    rows = [f"  {e.code:>3}  {e.meaning}" for e in EXIT_CODES]
    rows.insert(0, "    0  done")
    rows.append(f"  {REJECTED:>3}  a result was rejected (align spatial: F > k, no G-code)")
    return "exit codes (every subcommand):\n" + "\n".join(dict.fromkeys(rows))


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="milling-twin", description="Digital twin of CNC milling: co-simulate, align, calibrate, validate.",
        epilog=_exit_code_epilog(), formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"milling-twin {__version__}")
    parser.add_argument("--log-level", choices=LOG_LEVELS, default="warning",
                        help="messages shown on stderr (default warning; debug also prints tracebacks)")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def add(parent: argparse._SubParsersAction, command: Subcommand) -> None:
        p = parent.add_parser(command.name, help=command.help, description=command.help)
        command.arguments(p)
        p.set_defaults(handler=command.handler)

    for command in COMMANDS:
        if isinstance(command, Group):
            g = sub.add_parser(command.name, help=command.help, description=command.help)
            inner = g.add_subparsers(dest=f"{command.name}_command", required=True, metavar="COMMAND")
            for s in command.subcommands:
                add(inner, s)
        else:
            add(sub, command)
    return parser


def _handler(spec: str) -> Callable[[argparse.Namespace], int]:
    module, _, function = spec.partition(":")
    return getattr(importlib.import_module(module), function)


def exit_code_of(exc: BaseException) -> int | None:
    return next((e.code for e in EXIT_CODES if e.matches(exc)), None)


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="%(levelname)s %(name)s: %(message)s")
    try:
        return int(_handler(args.handler)(args))
    except BaseException as exc:  # noqa: BLE001 - mapped by EXIT_CODES; anything else propagates
        code = exit_code_of(exc)
        if code is None:
            raise
        if args.log_level == "debug":
            logging.getLogger("milling_twin").exception("%s failed", args.command)
        notes = "".join(f"; {note}" for note in getattr(exc, "__notes__", ()))
        text = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"error: {exc}"
        print(f"{text}{notes}", file=sys.stderr)
        return code
