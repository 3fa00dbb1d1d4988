"""The bad-input matrix of docs/testing.md ("Bad input: what you get"): the table cannot rot, because every row
names the test that proves it and ``test_every_row_of_the_readme_table_names_a_collected_test`` fails when
that test is not collected. Here too are the matrix's cases no other file covers: scenario files, recorded
data, calibration specs and parameter sets as the user meets them (load_scenario / load_spec, the message
after the file's path), and part programs through the Interpolator FMU."""
from __future__ import annotations

import re
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from conftest import CASE_CSV, REPO_ROOT
from fmu_helpers import ERROR, Slave, fmu_dir, fmu_file_name, require_fmu, status_of
from milling_twin.models import MODELS
from milling_twin.orchestrator.calibrate import CalibrationSpecError, load_spec
from milling_twin.orchestrator.calibrate.scenario_fit import prepare
from cases.calibration_synthetic import write_power_case
from milling_twin.cli import main
from milling_twin.orchestrator.scenario import ScenarioError, load_scenario

MATRIX = REPO_ROOT / "docs" / "testing.md"
SECTION = "## Bad input: what you get"


# ---- the table ----


def readme_rows() -> list[list[str]]:
    """The cells of the table under SECTION (header and separator left out)."""
    text = MATRIX.read_text()
    assert SECTION in text, f"{MATRIX} has no section {SECTION!r}"
    body = text.split(SECTION, 1)[1]
    rows, started = [], False
    for line in body.splitlines():
        if line.startswith("|"):
            started = True
            cells = [c.strip() for c in re.split(r"(?<!\\)\|", line.strip())[1:-1]]
            if not set("".join(cells)) <= set("-: "):
                rows.append(cells)
        elif started:
            break
    return rows[1:]  # without the header


def row_tests(cell: str) -> list[str]:
    return re.findall(r"`(tests/[\w/]+\.py::[^`]+)`", cell)


def collected(files: set[str]) -> set[str]:
    proc = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
                           *sorted(files)], cwd=REPO_ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return {line.strip() for line in proc.stdout.splitlines() if "::" in line}


def test_every_row_of_the_readme_table_names_a_collected_test() -> None:
    rows = readme_rows()
    assert len(rows) >= 60, f"only {len(rows)} rows under {SECTION!r}"
    header = [c.lower() for c in re.split(r"(?<!\\)\|", MATRIX.read_text().split(SECTION, 1)[1]
                                          .split("\n|", 1)[1].split("\n", 1)[0])]
    assert any("test" in c for c in header)
    wanted: dict[str, list[int]] = {}
    for number, cells in enumerate(rows, 1):
        assert len(cells) == 5, f"row {number}: 5 cells expected (what, tried, status, message, test): {cells}"
        assert cells[2] and cells[3], f"row {number}: status and message must be given: {cells}"
        tests = row_tests(cells[4])
        assert tests, f"row {number}: no test named in {cells[4]!r}"
        for test in tests:
            wanted.setdefault(test, []).append(number)
    ids = collected({t.split("::")[0] for t in wanted})
    missing = [f"row {', '.join(map(str, rows_))}: {test}" for test, rows_ in wanted.items()
               if test not in ids and not any(i.startswith(test + "[") for i in ids)]
    assert not missing, "docs/testing.md rows name tests that pytest does not collect:\n" + "\n".join(missing)


# ---- scenario files ----


def scenario_error(path: Path, fmu_dir: Path) -> str:
    """The message after "<scenario path>: ", with the scenario's folder written <dir>."""
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, fmu_dir)
    message = str(info.value)
    assert message.startswith(f"{path}: "), message
    return message.removeprefix(f"{path}: ").replace(str(path.parent), "<dir>")


SCENARIO_CASES = [  # (id, (old, new) edit of conftest.CASE_TOML, message)
    ("nan", ("c3 = 1.0", "c3 = nan"), "[fmus.power].parameters.c3: expected a finite number, got nan"),
    ("inf", ("c3 = 1.0", "c3 = inf"), "[fmus.power].parameters.c3: expected a finite number, got inf"),
    ("negative", ('P_idle = { value = 0.2, unit = "kW" }', "P_idle = -5.0"),
     "[fmus.power].parameters.P_idle: -5.0 W is outside the range [0.0, 100000.0] W that SpindlePower allows for "
     "'P_idle'"),
    ("zero interval", ("output_interval = 0.1", "output_interval = 0.0"),
     "[scenario].output_interval: must be > 0, got 0.0"),
    ("huge", ("c2 = 1000.0", "c2 = 1e300"),
     "[fmus.power].parameters.c2: 1e+300 W is outside the range [0.0, 1000000.0] W that SpindlePower allows for 'c2'"),
    ("huge stop time", ("output_interval = 0.1", "output_interval = 0.1\nstop_time = 1e300"),
     "[scenario].stop_time: simulated time [0.0, 1e+300] s exceeds the recorded data [0.0, 0.4] s"),
    ("tiny step", ("step_size = 0.1", "step_size = 1e-300"),
     "[fmus.mrr].step_size: step sizes (power: 1e-300, mrr: 0.1) are not integer multiples of a common base step "
     "of at least 1/10000 of the largest (their gcd is 0.1 s)"),
    ("unknown unit", ('unit = "kW" }', 'unit = "furlong" }'), None),
    ("string", ("c3 = 1.0", 'c3 = "1.0"'), "[fmus.power].parameters.c3: expected a finite number, got '1.0'"),
    ("boolean", ("c3 = 1.0", "c3 = true"), "[fmus.power].parameters.c3: expected a finite number, got True"),
    ("array", ("c3 = 1.0", "c3 = [1.0]"), "[fmus.power].parameters.c3: expected a finite number, got [1.0]"),
    ("fmi as string", ("fmi = 3", 'fmi = "3"'), "[fmus.power].fmi: must be 2 or 3, got '3'"),
    ("unit as number", ('unit = "kW" }', "unit = 3 }"), "[fmus.power].parameters.P_idle.unit: expected a string, got 3"),
    ("delay as string", ("delay = false", 'delay = "no"'),
     "[[connections]][0].delay: expected true or false, got 'no'"),
    ("record as string", ('record = ["power.P_total", "mrr.mrr", "power.spindle_on"]', 'record = "power.P_total"'),
     '[outputs].record: expected an array of "instance.variable" strings'),
    ("no name", ('name = "case"\n', ""), "[scenario].name: missing required key"),
    ("no fmu", ('fmu = "SpindlePower"\n', ""), "[fmus.power].fmu: missing required key"),
    ("no step size", ("step_size = 0.1\n", ""), "[fmus.power].step_size: missing required key"),
    ("no data file", ('file = "data.csv"\n', ""), "[recorded].file: missing required key"),
    ("data file missing", ('file = "data.csv"', 'file = "nope.csv"'), "[recorded].file: <dir>/nope.csv: file not found"),
]


@pytest.mark.parametrize("edit, message", [c[1:] for c in SCENARIO_CASES], ids=[c[0] for c in SCENARIO_CASES])
def test_scenario_values_types_and_keys(make_case, fmu_dir: Path, edit: tuple[str, str], message: str | None) -> None:
    got = scenario_error(make_case(edit), fmu_dir)
    if message is None:  # the list of known units is long: its start
        assert got.startswith("[fmus.power].parameters.P_idle: unit 'furlong' does not fit 'P_idle' (unit 'W'): "
                              "unknown unit 'furlong'; known units: 'm', 'm/s', "), got
    else:
        assert got == message


def test_scenario_file_empty_truncated_or_binary(make_case, fmu_dir: Path) -> None:
    path = make_case()
    text = path.read_text()
    path.write_text("")
    assert scenario_error(path, fmu_dir) == "[scenario]: missing required table"
    path.write_text(text[: len(text) // 2])
    assert scenario_error(path, fmu_dir) == "invalid TOML: Invalid value (at end of document)"
    path.write_text(text[: text.index("[fmus.mrr]")])  # cut at a line end: valid TOML, the rest missing
    assert scenario_error(path, fmu_dir) == "[scenario].stop_time: missing required key (no [recorded] data to default to)"
    path.write_bytes(b"\x00 garbage")
    assert scenario_error(path, fmu_dir) == "invalid TOML: Invalid statement (at line 1, column 1)"
    path.write_bytes(b"[scenario]\xff")
    assert scenario_error(path, fmu_dir) == ("line 1, column 11: byte 0xff is not valid UTF-8: the scenario file "
                                             "must be UTF-8 text")


# ---- recorded data files, as the scenario loads them ----

RECORDED_CASES = [  # (id, the data file, message after "[recorded].file: <dir>/data.csv")
    ("nan", CASE_CSV.replace("0.38", "nan"), ", line 3, column 'power': empty or NaN cell ('nan'); 1 such cell(s) "
                                             "in this column"),
    ("inf", CASE_CSV.replace("0.38", "inf"), ", line 3, column 'power': non-numeric or non-finite value 'inf'; 1 "
                                             "such cell(s) in this column"),
    ("overflow", CASE_CSV.replace("0.38", "1e400"), ", line 3, column 'power': non-numeric or non-finite value "
                                                    "'1e400'; 1 such cell(s) in this column"),
    ("text", CASE_CSV.replace("0.38", "abc"), ", line 3, column 'power': non-numeric or non-finite value 'abc'; 1 "
                                              "such cell(s) in this column"),
    ("empty", "", ": file is empty"),
    ("header only", CASE_CSV.split("\n")[0] + "\n", ": fewer than 2 data rows (found 0); a recording needs at least "
                                                    "2 samples"),
    ("truncated", CASE_CSV[:-20], ", line 5: truncated line: 4 fields, but the header (line 1) has 5 fields"),
]


@pytest.mark.parametrize("csv, message", [c[1:] for c in RECORDED_CASES], ids=[c[0] for c in RECORDED_CASES])
def test_recorded_file_values_and_truncation(make_case, fmu_dir: Path, csv: str, message: str) -> None:
    assert scenario_error(make_case(csv=csv), fmu_dir) == "[recorded].file: <dir>/data.csv" + message


def test_a_binary_recording_is_not_a_csv_recording(make_case, fmu_dir: Path) -> None:
    got = scenario_error(make_case(csv="\xff\xfe\x00binary"), fmu_dir)  # not CSV text: nothing of it is quoted
    assert got == "[recorded].file: <dir>/data.csv: not a CSV recording (binary content: byte 0x00 at line 1, column 3)"


# ---- calibration specs ----


def spec_error(spec: Path, tmp_path: Path, fmu_dir: Path | None = None) -> str:
    with pytest.raises(CalibrationSpecError) as info:
        loaded = load_spec(spec)
        if fmu_dir is not None:
            prepare(loaded, fmu_dir, tmp_path / "out")
    message = str(info.value)
    assert message.startswith(f"{spec}: "), message
    return message.removeprefix(f"{spec}: ")


SPEC_CASES = [  # (id, edit of the synthetic power spec, needs the FMUs, message)
    ("nan", ("min = 0.2", "min = nan"), False, '[parameters."power.c3"].min: expected a finite number, got nan'),
    ("inf", ("max = 2.0", "max = inf"), False, '[parameters."power.c3"].max: expected a finite number, got inf'),
    ("huge", ("max = 2.0", "max = 1e300"), True,
     "[parameters.\"power.c3\"].max: bounds [0.2, 1e+300] leave the FMU's range [0.1, 3.0] of power.c3"),
    ("negative", ("min = 0.2", "min = -1.0"), True,
     "[parameters.\"power.c3\"].min: bounds [-1.0, 2.0] leave the FMU's range [0.1, 3.0] of power.c3"),
    ("string", ("min = 0.2", 'min = "0.2"'), False, '[parameters."power.c3"].min: expected a finite number, got \'0.2\''),
    ("fraction", ("[solver]\nstarts = 3", "[solver]\nstarts = 2.5"), False,
     "[solver].starts: expected a whole number >= 1, got 2.5"),
    ("no scenario", ('scenario = "power_case.toml"\n', ""), False, "[calibration].scenario: missing required key"),
]


@pytest.mark.parametrize("edit, full, message", [c[1:] for c in SPEC_CASES], ids=[c[0] for c in SPEC_CASES])
def test_calibration_spec_values_types_and_keys(tmp_path: Path, fmu_dir: Path, edit: tuple[str, str], full: bool,
                                                message: str) -> None:
    spec = write_power_case(tmp_path / "case")
    text = spec.read_text()
    assert edit[0] in text
    spec.write_text(text.replace(*edit, 1))
    assert spec_error(spec, tmp_path, fmu_dir if full else None) == message


def test_calibration_spec_empty_or_truncated(tmp_path: Path) -> None:
    spec = write_power_case(tmp_path / "case")
    text = spec.read_text()
    spec.write_text("")
    assert spec_error(spec, tmp_path) == "[calibration]: missing required table"
    spec.write_text(text[: text.index("[segments]")])
    assert spec_error(spec, tmp_path) == "[segments]: missing required table"
    spec.write_text(text[: text.index("[segments]") + 25])
    assert spec_error(spec, tmp_path) == "invalid TOML: Unclosed array (at end of document)"


def test_a_scenario_file_given_as_a_calibration_spec_and_the_reverse(make_case, tmp_path: Path,
                                                                      fmu_dir: Path) -> None:
    """Each loader recognises the other kind of file and says which command takes it."""
    case = make_case()
    assert spec_error(case, tmp_path) == (f"this is a scenario file ([scenario] table), not a calibration spec: "
                                          f"use `milling-twin run {case}`")
    spec = write_power_case(tmp_path / "case")
    with pytest.raises(ScenarioError) as info:
        load_scenario(spec, fmu_dir)
    assert str(info.value) == (f"{spec}: this is a calibration spec ([calibration] table), not a scenario file: "
                               f"use `milling-twin calibrate {spec}`")


@pytest.mark.parametrize("folder", ["missing", "empty", "other FMUs"])
def test_a_missing_fmu_says_how_to_build_them(make_case, tmp_path: Path, fmu_dir: Path, folder: str) -> None:
    hint = ("build the FMUs first: `make build` (or `cmake -S . -B build && cmake --build build`), or pass "
            "--fmu-dir / set MILLING_TWIN_FMU_DIR")
    case = make_case()
    where = tmp_path / "fmus"
    if folder != "missing":
        where.mkdir()
    if folder == "other FMUs":
        (where / "Other.fmu").write_bytes(b"")
    state = {"missing": f"{where} does not exist", "empty": f"{where} holds no FMUs",
             "other FMUs": f"available in {where}: Other"}[folder]
    assert scenario_error(case, where) == (f"[fmus.power].fmu: FMU 'SpindlePower' not found: looked for "
                                           f"{where / 'SpindlePower.fmu'}; {state}; {hint}").replace(str(tmp_path),
                                                                                                    "<dir>")


# ---- parameter sets ----

SET_CASES = [  # (id, the set file, message after "[scenario].parameter_sets[0]: <dir>/set.toml: ")
    ("empty", "", "[parameters]: expected [parameters.<instance>] tables of values"),
    ("truncated", "[parameters.power]\nc1 = ", "invalid TOML: Invalid value (at end of document)"),
    ("nan", "[parameters.power]\nc1 = nan\n", "[parameters.power].c1: expected a finite number, got nan"),
    ("inf", "[parameters.power]\nc1 = inf\n", "[parameters.power].c1: expected a finite number, got inf"),
    ("huge", "[parameters.power]\nc1 = 1e300\n",
     "[parameters.power].c1: 1e+300 W.s/rad is outside the range [0.0, 1000.0] W.s/rad that SpindlePower allows for "
     "'c1'"),
    ("negative", "[parameters.power]\nc1 = -1.0\n",
     "[parameters.power].c1: -1.0 W.s/rad is outside the range [0.0, 1000.0] W.s/rad that SpindlePower allows for "
     "'c1'"),
    ("string", '[parameters.power]\nc1 = "0.5"\n', "[parameters.power].c1: expected a finite number, got '0.5'"),
    ("wrong unit", '[parameters.power]\nc1 = { value = 1.0, unit = "mm" }\n',
     "[parameters.power].c1: unit 'mm' does not fit 'c1' (unit 'W.s/rad'): cannot convert 'mm' to 'W.s/rad': "
     "dimensions differ (length vs power per angular velocity)"),
    ("not a table", "[parameters]\npower = 3\n", "[parameters.power]: expected a table, got 3"),
    ("binary", "\x00\x01", "invalid TOML: Invalid statement (at line 1, column 1)"),
]


@pytest.mark.parametrize("body, message", [c[1:] for c in SET_CASES], ids=[c[0] for c in SET_CASES])
def test_parameter_set_values_types_and_truncation(make_case, fmu_dir: Path, body: str, message: str) -> None:
    path = make_case(("output_interval = 0.1", 'output_interval = 0.1\nparameter_sets = ["set.toml"]'))
    (path.parent / "set.toml").write_text(body)
    assert scenario_error(path, fmu_dir) == f"[scenario].parameter_sets[0]: <dir>/set.toml: {message}"


# ---- part programs, through the Interpolator FMU ----

PROGRAM_CASES = [  # (id, program, line, the message's tail)
    ("truncated in a word", "G1 X10 F600\nG1 Y", 2, "\"G1 Y\": a number after 'Y'"),
    ("truncated NURBS block", "G0 X1\nG6.2 P3 K0 X1 Y0 R1 F600\nK0 X2 Y1 R1\n", 3,
     '"K0 X2 Y1 R1": at least degree + 1 = 3 control points in the NURBS block started in line 2, got 2'),
    ("huge coordinate", "G1 X99999999999999999 F600\n", 1,
     '"G1 X99999999999999999 F600": a coordinate of magnitude at most 1e+06'),
    ("huge feed", "G1 X10 F99999999999999999\n", 1,
     '"G1 X10 F99999999999999999": a feed F > 0 and at most 1e+07, got F99999999999999999'),
    ("zero feed", "G1 X10 F0\n", 1, '"G1 X10 F0": a feed F > 0 and at most 1e+07, got F0'),
    ("negative feed", "G1 X10 F-600\n", 1, '"G1 X10 F-600": a feed F > 0 and at most 1e+07, got F-600'),
    ("negative spindle speed", "G1 X10 F600\nS-100 M3\n", 2, '"S-100 M3": a spindle speed S of 0 to 1e+06 rpm, got S-100'),
    ("nan", "G1 Xnan F600\n", 1, "\"G1 Xnan F600\": a number after 'X'"),
    ("inf", "G1 Xinf F600\n", 1, "\"G1 Xinf F600\": a number after 'X'"),
    ("exponent", "G1 X1e3 F600\n", 1,
     "\"G1 X1e3 F600\": a word G, M, N, O, T, X, Y, Z, I, J, K, R, F, S, P, L, H, D or Q, got 'e'"),
    ("binary", "\xff\xfe\x00\x01", 1,
     '"????": a word (letter and number), a comment or the end of the line, got a non-ASCII character'),
]


@pytest.mark.parametrize("version", [3, 2])
@pytest.mark.parametrize("text, line, tail", [c[1:] for c in PROGRAM_CASES], ids=[c[0] for c in PROGRAM_CASES])
def test_part_program_values_and_truncation(tmp_path: Path, version: int, text: str, line: int, tail: str) -> None:
    program = tmp_path / "part.nc"
    program.write_bytes(text.encode("latin-1"))
    with Slave(require_fmu(fmu_dir() / fmu_file_name("Interpolator", version))) as slave:
        slave.instantiate()
        slave.enter_initialization()
        slave.fmu.setString([slave.vr["program"]], [str(program)])
        assert status_of(lambda: slave.exit_initialization()) == ERROR
        assert slave.last_error() == f"exitInitializationMode: part program {program} line {line}: {tail}"


# ---- an FMU whose model description and binary do not belong together, run by the orchestrator ----


def _with_token(src: Path, dst: Path, token: str) -> None:
    """A copy of the FMU whose model description carries ``token`` (FMI 3 instantiationToken, FMI 2 guid)."""
    with zipfile.ZipFile(src) as zin, zipfile.ZipFile(dst, "w") as zout:
        for item in zin.infolist():
            data = zin.read(item)
            if item.filename == "modelDescription.xml":
                data, n = re.subn(rb'(instantiationToken|guid)="\{[^}]*\}"', rb'\1="' + token.encode() + b'"', data)
                assert n == 1
            zout.writestr(item, data)


@pytest.mark.parametrize("fmi", [3, 2])
@pytest.mark.parametrize("stepping", ["python", "fast"])
def test_a_wrong_token_in_a_scenario_fmu_is_one_clean_error(make_case, fmu_dir: Path, tmp_path: Path, capsys,
                                                             fmi: int, stepping: str) -> None:
    """The FMU refuses to instantiate: the CLI prints the FMU's own message (no traceback) and exits 1."""
    wrong = "{00000000-0000-0000-0000-000000000000}"
    bad = tmp_path / "Bad.fmu"
    _with_token(fmu_dir / fmu_file_name("SpindlePower", fmi), bad, wrong)
    path = make_case(('fmu = "SpindlePower"\nfmi = 3', f'fmu = "{bad}"\nfmi = {fmi}'))
    code = main(["run", str(path), "--fmu-dir", str(fmu_dir), "--out", str(tmp_path / "runs"), "--no-progress",
                 "--path", stepping])
    err = capsys.readouterr().err
    function = "fmi3InstantiateCoSimulation" if fmi == 3 else "fmi2Instantiate"
    token = MODELS["SpindlePower"].instantiation_token()
    assert code == 1 and err == (
        f"error: instantiate of instance 'power' at t = 0.0 s returned NULL: {function}: wrong instantiation "
        f"token/GUID '{wrong}'; this FMU (SpindlePower) has '{token}': the model description and the binary do not "
        f"belong together; results so far in {tmp_path / 'runs' / 'case'}\n")


@pytest.mark.parametrize("fmi", [3, 2])
def test_an_fmu_without_a_binary_for_this_platform_is_a_scenario_error(make_case, fmu_dir: Path, tmp_path: Path,
                                                                        fmi: int) -> None:
    """Caught when the scenario is read (fmpy would fail at instantiation with a bare Exception)."""
    platform = "x86_64-linux" if fmi == 3 else "linux64"
    library = f"binaries/{platform}/SpindlePower.so"
    for other, holds in ((None, "nothing"), ("aarch64-darwin", "aarch64-darwin")):
        bad = tmp_path / f"NoBinary{other or ''}.fmu"
        with zipfile.ZipFile(fmu_dir / fmu_file_name("SpindlePower", fmi)) as zin, zipfile.ZipFile(bad, "w") as zout:
            for item in zin.infolist():
                if item.filename.startswith("binaries/"):
                    if other is None:
                        continue
                    zout.writestr(item.filename.replace(platform, other), zin.read(item))
                else:
                    zout.writestr(item, zin.read(item))
        path = make_case(('fmu = "SpindlePower"\nfmi = 3', f'fmu = "{bad.name}"\nfmi = {fmi}'))
        assert scenario_error(path, fmu_dir) == (f"[fmus.power].fmu: <dir>/{bad.name} has no binary for this platform "
                                                 f"({library}); its binaries/ holds {holds}")


def test_a_broken_fmu_file_is_a_scenario_error(make_case, fmu_dir: Path) -> None:
    path = make_case(('fmu = "SpindlePower"', 'fmu = "t.fmu"'))
    data = (fmu_dir / "SpindlePower.fmu").read_bytes()
    for content in (b"", data[: len(data) // 2], b"hello"):
        (path.parent / "t.fmu").write_bytes(content)
        assert scenario_error(path, fmu_dir) == ("[fmus.power].fmu: cannot read the model description of <dir>/t.fmu: "
                                                 "File is not a zip file")


def test_an_unwritable_results_folder_is_one_clean_error(make_case, fmu_dir: Path, tmp_path: Path, capsys) -> None:
    (tmp_path / "afile").write_text("")
    out = tmp_path / "afile" / "runs"
    code = main(["run", str(make_case()), "--fmu-dir", str(fmu_dir), "--out", str(out), "--no-progress"])
    assert code == 1 and capsys.readouterr().err == (
        f"error: cannot write the results to {out / 'case'}: [Errno 20] Not a directory: '{out / 'case'}'\n")
