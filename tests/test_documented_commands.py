"""Every command the README and docs/ show in a ```sh block is checked: each milling-twin command parses
with the real parser (so a renamed subcommand or option fails here), each make target exists, cheap ones
run for real, and a line of any other program fails unless that program is listed below."""
from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO_ROOT
from milling_twin.cli import build_parser

DOCUMENTS = [REPO_ROOT / "README.md", *sorted((REPO_ROOT / "docs").glob("*.md"))]
# programs a reader runs that are not ours: shown, not run here
EXTERNAL = {"cmake", "git", "chromium", "xdg-open", "open", "pip", "python3", "fmpy", "sh", "bash", "cd", "ctest",
            "valgrind", "apt-get", "export", "ls", "cat", "sudo", "sha256sum", "python"}
# milling-twin subcommands cheap enough to run from the docs as they stand (a few seconds each)
RUN = {"run", "info", "lobes", "calibrate", "sweep", "--version"}
FENCE = re.compile(r"^```sh\s*\n(.*?)^```", re.M | re.S)
PYTHON = re.compile(r"^```python\s*\n(.*?)^```", re.M | re.S)


def documented_commands() -> list[tuple[str, int, str]]:
    """(document, line number, command) of each command line in a ```sh block (continuations joined)."""
    found = []
    for doc in DOCUMENTS:
        text = doc.read_text()
        for block in FENCE.finditer(text):
            start = text[:block.start(1)].count("\n") + 1
            pending, first = "", 0
            for offset, line in enumerate(block.group(1).splitlines()):
                if not pending:
                    first = start + offset
                pending += line.rstrip("\\").strip() + " " if line.rstrip().endswith("\\") else line.strip()
                if line.rstrip().endswith("\\"):
                    continue
                words = shlex.split(pending, comments=True)
                if words:
                    found.append((doc.relative_to(REPO_ROOT).as_posix(), first, pending))
                pending = ""
    return found


def _words(command: str) -> list[str]:
    words = shlex.split(command, comments=True)
    while words and re.fullmatch(r"[A-Z_]+=\S*", words[0]):  # VAR=value prefixes
        words = words[1:]
    return words


def distinct_commands(found: list[tuple[str, int, str]]) -> list[tuple[str, str]]:
    """(every place it is shown, command) of each distinct command, in the order of its first place: README and
    the topic pages show some of the same commands (the calibration of every UMich run in two places), which run
    once here; a failure names every place."""
    shown: dict[str, tuple[str, list[str]]] = {}  # by its words: (the command as first written, its places)
    for doc, line, command in found:
        shown.setdefault(" ".join(_words(command)), (command, []))[1].append(f"{doc}:{line}")
    return [(", ".join(places), command) for command, places in shown.values()]


COMMANDS = documented_commands()
DISTINCT_COMMANDS = distinct_commands(COMMANDS)


SHARED = REPO_ROOT.parent / "shared"  # the data beside the repository (../shared in the docs' commands)


def _workspace(tmp_path: Path, fmu_dir: Path) -> tuple[Path, dict[str, str]]:
    """A folder where the relative paths of the docs resolve and results stay apart (with ../shared beside it
    as beside the repository); the folder and the environment."""
    folder = tmp_path / "repo"
    folder.mkdir()
    (folder / "scenarios").symlink_to(REPO_ROOT / "scenarios")
    (folder / "studies").symlink_to(REPO_ROOT / "studies")
    (folder / "build").mkdir()
    (folder / "build" / "fmus").symlink_to(fmu_dir)
    if SHARED.is_dir():
        (tmp_path / "shared").symlink_to(SHARED)
    return folder, {**os.environ, "MILLING_TWIN_FMU_DIR": str(fmu_dir)}


PYTHON_BLOCKS = [(doc.relative_to(REPO_ROOT).as_posix(), doc.read_text()[:m.start()].count("\n") + 1, m.group(1))
                 for doc in DOCUMENTS for m in PYTHON.finditer(doc.read_text())]


@pytest.mark.parametrize("doc, line, code", PYTHON_BLOCKS, ids=[f"{d}:{n}" for d, n, _ in PYTHON_BLOCKS])
def test_documented_python(doc: str, line: int, code: str, tmp_path: Path, fmu_dir: Path) -> None:
    """Each ```python block runs as written (after the run the docs show first, whose folder it may read)."""
    folder, env = _workspace(tmp_path, fmu_dir)
    subprocess.run([sys.executable, "-m", "milling_twin", "run", "scenarios/umich_power.toml", "--no-progress"],
                   cwd=folder, env=env, capture_output=True, timeout=600, check=True)
    proc = subprocess.run([sys.executable, "-c", code], cwd=folder, env=env, capture_output=True, text=True,
                          timeout=600)
    assert proc.returncode == 0, f"{doc}:{line}:\n{proc.stderr[-3000:]}"


def test_the_docs_show_commands() -> None:
    assert len(COMMANDS) >= 5, COMMANDS
    assert any(_words(c)[0] == "make" and "demo" in c for _, _, c in COMMANDS)


def test_a_command_shown_twice_runs_once_and_names_both_places() -> None:
    found = [("README.md", 3, "milling-twin run a.toml"), ("docs/x.md", 7, "milling-twin  run a.toml  # again"),
             ("docs/x.md", 9, "milling-twin run b.toml")]
    assert distinct_commands(found) == [("README.md:3, docs/x.md:7", "milling-twin run a.toml"),
                                        ("docs/x.md:9", "milling-twin run b.toml")]


@pytest.mark.parametrize("where, command", DISTINCT_COMMANDS, ids=[w.split(",")[0] for w, _ in DISTINCT_COMMANDS])
def test_documented_command(where: str, command: str, tmp_path: Path, fmu_dir: Path) -> None:
    """Each distinct command once (`where`: every place the docs show it)."""
    words = _words(command)
    program = Path(words[0]).name
    if program == "make":
        targets = [w for w in words[1:] if not w.startswith("-") and "=" not in w]
        proc = subprocess.run(["make", "-n", *targets], cwd=REPO_ROOT, capture_output=True, text=True, timeout=60)
        assert proc.returncode == 0, f"{where}: {command}: {proc.stderr}"
        return
    if program in ("python", "python3") and words[1:3] == ["-m", "milling_twin"]:
        words, program = ["milling-twin", *words[3:]], "milling-twin"
    if program != "milling-twin":
        assert program in EXTERNAL, f"{where}: {command!r}: a command of {program!r} is not covered; " \
                                    "make it a milling-twin or make command, or list the program in EXTERNAL"
        return
    arguments = words[1:]
    try:
        build_parser().parse_args(arguments)
    except SystemExit as exc:
        if exc.code != 0:  # --help and --version exit 0
            pytest.fail(f"{where}: {command!r} does not parse (exit {exc.code})")
    subcommand = next((w for w in arguments if not w.startswith("-")), arguments[0] if arguments else "")
    if subcommand not in RUN or "--help" in arguments:
        return
    if "../shared" in command and not SHARED.is_dir():
        pytest.skip(f"{where}: reads the data beside the repository, and {SHARED} does not exist")
    folder, env = _workspace(tmp_path, fmu_dir)  # run it as written
    if "--parameter-set" in arguments:  # written by the calibration the docs show before it
        subprocess.run([sys.executable, "-m", "milling_twin", "calibrate", "scenarios/calibration/umich_power.toml",
                        "--no-progress"], cwd=folder, env=env, capture_output=True, timeout=600, check=True)
    proc = subprocess.run([sys.executable, "-m", "milling_twin", *arguments], cwd=folder, env=env,
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, f"{where}: {command}\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
