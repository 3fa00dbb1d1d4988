"""Compatibility check of the built FMUs with importers other than fmpy: runs every FMU (FMI 2 and FMI 3) with random
parameters and constant inputs through each importer and compares every output at every communication point with
fmpy's ``simulate_fmu`` given the same start values. Prints (and with --markdown writes) a table FMU x importer with
pass/fail and the largest relative difference (the measure of tests/fmu_helpers.assert_close; pass: <= 1e-9).

Importers (each skipped with a reason when it cannot be had):
- ``fmi4j``:   FMI4j 0.38 on the JVM through tests/importers/fmi4j (needs java and mvn; FMI 1/2 only).
- ``fmi-sim``: the Rust ``fmi-sim`` from crates.io, built with ``cargo install`` into --tools-dir (25.5 min
               with one job on two cores; --jobs sets cargo's -j). Or give a built one with --fmi-sim PATH.
- ``fmusim``:  the Modelica Reference-FMUs ``fmusim``, which no package registry carries: give its path with
               --fmusim PATH (a release archive of github.com/modelica/Reference-FMUs holds it for Linux, Windows and
               macOS; or build it from a clone as its README says).

Usage (from the repository, after `make fmus`):
    .venv/bin/python tests/importers/compat.py [--importers fmi4j,fmi-sim,fmusim] [--markdown results.md]
"""
from __future__ import annotations

import argparse
import csv
import os
import shutil
import subprocess
import sys
import tempfile
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
sys.path.insert(0, str(REPO / "tests"))

import fmpy  # noqa: E402

from fmu_helpers import (  # noqa: E402
    all_fmus,
    fmu_dir,
    model_of,
    numeric_parameters,
    random_arguments,
    scalar_inputs,
    split_fmu_name,
)

FMI_SIM_VERSION = "0.7.0"
RTOL = 1e-9
STEP_SIZE = 1e-3
STEPS = 10


@dataclass
class Case:
    """One FMU with its start values (parameters and constant inputs) and the outputs to compare."""
    fmu: Path
    version: int
    starts: dict[str, float]
    types: dict[str, str]
    outputs: list[str]
    reference: dict[str, np.ndarray] = field(default_factory=dict)  # output -> (steps + 1, n) from t = 0

    def literal(self, name: str, boolean_words: bool = True) -> str:
        kind, value = self.types[name], self.starts[name]
        if kind == "Boolean":
            return ("true" if value else "false") if boolean_words else str(int(value))
        return str(int(value)) if kind == "Int32" else repr(float(value))


@dataclass
class Outcome:
    importer: str
    fmu: str
    ok: bool | None  # None: not run
    difference: float | None = None
    note: str = ""

    def cell(self) -> str:
        if self.ok is None:
            return f"not run ({self.note})" if self.note else "not run"
        text = "pass" if self.ok else "fail"
        if self.difference is not None:
            text += f", {self.difference:.1e}"
        return text + (f" ({self.note})" if self.note else "")


def make_case(fmu: Path) -> Case:
    """The random point of the libcosim and FMI4j tests (rng 11): parameters from row 5, inputs from row 2."""
    _, version = split_fmu_name(fmu)
    model = model_of(fmu)
    values = random_arguments(model, 12, np.random.default_rng(11))
    starts = {v.name: float(values[v.name][5]) for v in numeric_parameters(model)}
    starts.update({v.name: float(values[v.name][2]) for v in scalar_inputs(model)})
    types = {name: model.variable(name).type for name in starts}
    case = Case(fmu, version, starts, types, [v.name for v in model.of("output")])
    case.reference = fmpy_reference(case)
    return case


def fmpy_reference(case: Case) -> dict[str, np.ndarray]:
    """fmpy's simulate_fmu from t = 0 (the point after initialization first); an FMI 2 array is its scalars
    "name[i,j]" in model description order, an FMI 3 array one variable, flattened row-major."""
    starts = {n: (bool(v) if case.types[n] == "Boolean" else int(v) if case.types[n] == "Int32" else v)
              for n, v in case.starts.items()}
    names = [v.name for v in fmpy.read_model_description(str(case.fmu)).modelVariables]
    columns = {o: [n for n in names if n == o or n.startswith(o + "[")] for o in case.outputs}
    result = fmpy.simulate_fmu(str(case.fmu), start_values=starts, stop_time=STEPS * STEP_SIZE,
                               output_interval=STEP_SIZE, output=[c for cs in columns.values() for c in cs],
                               logger=lambda *args: None)
    return {o: np.hstack([np.asarray(result[c], dtype=float).reshape(len(result), -1) for c in cs])
            for o, cs in columns.items()}


def read_csv(path: Path) -> tuple[list[str], list[list[str]]]:
    with path.open(newline="") as f:
        rows = [r for r in csv.reader(f) if r]
    if not rows:
        raise ValueError(f"{path} is empty")
    return [h.strip() for h in rows[0]], rows[1:]


def number(text: str) -> float:
    """A CSV value: a number, or a Boolean written as a word."""
    word = text.strip().lower()
    return 1.0 if word == "true" else 0.0 if word == "false" else float(text)


def compare(case: Case, path: Path, importer: str) -> Outcome:
    """Every output of ``case`` in the importer's CSV ``path`` (a time column and one column per output, or per FMI 2
    array element, or an FMI 3 array's values separated by spaces) against fmpy at the same communication points."""
    header, rows = read_csv(path)
    if "time" not in header:
        return Outcome(importer, case.fmu.name, False, note=f"{path.name}: no time column in {header[:5]}")
    times = np.array([float(r[header.index("time")]) for r in rows])
    index = np.rint(times / STEP_SIZE).astype(int)
    keep = (index >= 0) & (index <= STEPS) & np.isclose(times, index * STEP_SIZE, rtol=1e-9, atol=1e-15)
    if not keep.any():
        return Outcome(importer, case.fmu.name, False, note=f"{path.name}: no row on the communication points")
    worst = 0.0
    for name in case.outputs:
        columns = [i for i, h in enumerate(header) if h == name or h.startswith(name + "[")]
        if not columns:
            return Outcome(importer, case.fmu.name, False, note=f"output {name} missing from {path.name}")
        actual = []
        for r, k in zip(rows, keep):
            if k:
                actual.append([number(x) for i in columns for x in r[i].replace(";", " ").split()])
        expected = case.reference[name][index[keep]]
        if any(len(a) != expected.shape[1] for a in actual):
            return Outcome(importer, case.fmu.name, False,
                           note=f"{name}: {len(actual[0])} values per row, fmpy has {expected.shape[1]}")
        actual_array = np.array(actual, dtype=float)
        scale = np.maximum(np.abs(expected), np.max(np.abs(expected), axis=0, keepdims=True))
        error = np.abs(actual_array - expected)
        relative = np.where(scale > 0, error / np.where(scale > 0, scale, 1.0), error)
        worst = max(worst, float(np.max(relative)) if relative.size else 0.0)
    return Outcome(importer, case.fmu.name, bool(worst <= RTOL), worst)


# ---- the importers ----


def run(command: list[str], what: str, timeout: float = 600) -> str | None:
    """None on success, else a one-line reason naming ``what``."""
    try:
        done = subprocess.run(command, capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.TimeoutExpired) as error:
        return f"{what}: {error}"
    if done.returncode != 0:
        lines = [line.strip() for line in (done.stderr + done.stdout).splitlines() if line.strip()]
        errors = [line for line in lines if "error" in line.lower()] or lines[-1:]
        return f"{what} exited {done.returncode}: {errors[0][:200] if errors else ''}"
    return None


class Fmi4j:
    name = "fmi4j"

    def __init__(self, tools: Path):
        self.jar: Path | None = None
        self.reason = ""
        missing = [t for t in ("java", "mvn") if shutil.which(t) is None]
        if missing:
            self.reason = f"{' and '.join(missing)} not on PATH"
            return
        build = tools / "fmi4j"
        error = run(["mvn", "-q", "-B", "-f", str(HERE / "fmi4j" / "pom.xml"), "package", f"-DbuildDir={build}"],
                    "mvn package of tests/importers/fmi4j")
        if error:
            self.reason = error
        else:
            self.jar = build / "fmi4j-driver.jar"

    def simulate(self, case: Case, work: Path) -> Outcome:
        if case.version != 2:
            return Outcome(self.name, case.fmu.name, None, note="FMI4j 0.38 imports FMI 1/2 only")
        plan = work / "plan.csv"
        lines = [f"step_size,{STEP_SIZE!r}", f"steps,{STEPS}"]
        lines += [f"start,{n},{case.literal(n, boolean_words=False)}" for n in case.starts]
        plan.write_text("\n".join(lines) + "\n")
        out = work / "fmi4j.csv"
        error = run(["java", "-jar", str(self.jar), str(case.fmu), str(plan), str(out)], "FMI4j driver")
        return Outcome(self.name, case.fmu.name, False, note=error) if error else compare(case, out, self.name)


class FmiSim:
    name = "fmi-sim"

    def __init__(self, tools: Path, binary: str | None, build: bool, jobs: int):
        self.binary: Path | None = Path(binary) if binary else tools / "fmi-sim" / "bin" / "fmi-sim"
        self.reason = ""
        if self.binary.is_file():
            return
        if binary:
            self.reason, self.binary = f"{binary}: no such file", None
        elif not build:
            self.reason, self.binary = f"{self.binary} not built (run without --no-build)", None
        elif shutil.which("cargo") is None:
            self.reason, self.binary = "cargo not on PATH (rustup.rs)", None
        else:
            print(f"building fmi-sim {FMI_SIM_VERSION} with cargo -j{jobs} (25.5 min with one job on two shared cores)",
                  file=sys.stderr)
            error = run(["nice", "-n", "19", "cargo", "install", "fmi-sim", "--version", FMI_SIM_VERSION,
                         "--root", str(tools / "fmi-sim"), "-j", str(jobs)], "cargo install fmi-sim", timeout=4 * 3600)
            if error:
                self.reason, self.binary = error, None

    def simulate(self, case: Case, work: Path) -> Outcome:
        out = work / "fmi-sim.csv"
        command = [str(self.binary), "--model", str(case.fmu), "-o", str(out), "co-simulation", "-s", "0",
                   "-f", repr(STEPS * STEP_SIZE), "--step", repr(STEP_SIZE), "--output-interval", repr(STEP_SIZE),
                   "-n", "0"]
        for n in case.starts:
            command += ["--init-values", f"{n}={case.literal(n)}"]
        error = run(command, "fmi-sim")
        return Outcome(self.name, case.fmu.name, False, note=error) if error else compare(case, out, self.name)


class FmuSim:
    name = "fmusim"

    def __init__(self, binary: str | None):
        self.binary = Path(binary) if binary else None
        self.reason = ""
        if self.binary is None:
            self.reason = "give --fmusim PATH (Reference-FMUs release or own build; not on any package registry)"
        elif not self.binary.is_file():
            self.reason, self.binary = f"{binary}: no such file", None

    def simulate(self, case: Case, work: Path) -> Outcome:
        out = work / "fmusim.csv"
        command = [str(self.binary), "--interface-type", "cs", "--stop-time", repr(STEPS * STEP_SIZE),
                   "--output-interval", repr(STEP_SIZE), "--output-file", str(out)]
        for n in case.starts:
            command += ["--start-value", n, case.literal(n)]
        error = run(command + [str(case.fmu)], "fmusim")
        return Outcome(self.name, case.fmu.name, False, note=error) if error else compare(case, out, self.name)


def markdown(outcomes: list[Outcome], importers: list[str], notes: dict[str, str]) -> str:
    fmus = list(dict.fromkeys(o.fmu for o in outcomes))
    cells = {(o.fmu, o.importer): o.cell() for o in outcomes}
    lines = ["| FMU | " + " | ".join(importers) + " |", "|---" * (len(importers) + 1) + "|"]
    for fmu in fmus:
        lines.append(f"| {fmu} | " + " | ".join(cells.get((fmu, i), "not run" if i in notes else "")
                                                  for i in importers) + " |")
    for importer, note in notes.items():
        lines.append(f"\n{importer}: not run: {note}")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--fmu-dir", type=Path, default=None, help="built FMUs (default: $MILLING_TWIN_FMU_DIR or "
                        "build/fmus)")
    parser.add_argument("--importers", default="fmi4j,fmi-sim,fmusim")
    parser.add_argument("--tools-dir", type=Path, default=Path.home() / ".cache" / "milling-twin-importers",
                        help="where the FMI4j driver and fmi-sim are built")
    parser.add_argument("--fmi-sim", default=None, help="a built fmi-sim executable (else cargo install)")
    parser.add_argument("--fmusim", default=None, help="a built fmusim executable")
    parser.add_argument("--no-build", action="store_true", help="do not run cargo install")
    parser.add_argument("--jobs", type=int, default=1, help="cargo build jobs (default 1)")
    parser.add_argument("--markdown", type=Path, default=None, help="write the table here too")
    args = parser.parse_args(argv)

    if args.fmu_dir is not None:
        os.environ["MILLING_TWIN_FMU_DIR"] = str(args.fmu_dir.resolve())
    folder = fmu_dir()
    fmus = [p for p in all_fmus(folder) if p.is_file()]
    if not fmus:
        print(f"compat: no FMUs in {folder}: build them first (make fmus)", file=sys.stderr)
        return 2
    wanted = [i.strip() for i in args.importers.split(",") if i.strip()]
    unknown = sorted(set(wanted) - {"fmi4j", "fmi-sim", "fmusim"})
    if unknown:
        print(f"compat: --importers: unknown {unknown} (fmi4j, fmi-sim, fmusim)", file=sys.stderr)
        return 2
    args.tools_dir.mkdir(parents=True, exist_ok=True)
    importers = []
    for name in wanted:
        if name == "fmi4j":
            importers.append(Fmi4j(args.tools_dir))
        elif name == "fmi-sim":
            importers.append(FmiSim(args.tools_dir, args.fmi_sim, not args.no_build, args.jobs))
        else:
            importers.append(FmuSim(args.fmusim))
    notes = {i.name: i.reason for i in importers if i.reason}

    outcomes: list[Outcome] = []
    with tempfile.TemporaryDirectory(prefix="milling-twin-compat-") as tmp:
        for fmu in fmus:
            case = make_case(fmu)
            for importer in importers:
                if importer.reason:
                    continue
                work = Path(tmp) / f"{fmu.stem}-{importer.name}"
                work.mkdir()
                outcome = importer.simulate(case, work)
                outcomes.append(outcome)
                print(f"{fmu.name:28s} {importer.name:8s} {outcome.cell()}", file=sys.stderr)
    table = markdown(outcomes, [i.name for i in importers], notes)
    print(table)
    if args.markdown:
        args.markdown.write_text(table)
    return 0 if all(o.ok is not False for o in outcomes) else 1


if __name__ == "__main__":
    sys.exit(main())
