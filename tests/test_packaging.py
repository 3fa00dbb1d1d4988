"""The package's shape: one namespace in site-packages, definitions that never import the orchestrator."""
from __future__ import annotations

import ast
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

from conftest import REPO_ROOT

# What models/ (the equations, milling_twin.models) may not import: everything built on top of it.
LAYERS_ABOVE_MODELS = ("milling_twin.orchestrator", "milling_twin.training", "milling_twin.cli", "milling_twin.api",
                       "milling_twin.commands", "milling_twin.datasets", "orchestrator")
PACKAGE_FOLDERS = {"milling_twin": "milling_twin", "models": "milling_twin/models",
                   "orchestrator": "milling_twin/orchestrator"}


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, module) of every import in ``path``, static or through importlib.import_module("...")."""
    found = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            found.append((node.lineno, node.module))
            found += [(node.lineno, f"{node.module}.{alias.name}") for alias in node.names]
        elif (isinstance(node, ast.Call) and getattr(node.func, "attr", getattr(node.func, "id", "")) == "import_module"
              and node.args and isinstance(node.args[0], ast.Constant)):
            found.append((node.lineno, str(node.args[0].value)))
    return found


def test_the_definitions_import_nothing_built_on_them() -> None:
    sources = sorted((REPO_ROOT / "models").rglob("*.py"))
    assert len(sources) >= 10
    offending = [f"{p.relative_to(REPO_ROOT)}:{line}: imports {name}" for p in sources for line, name in _imports(p)
                 if any(name == layer or name.startswith(layer + ".") for layer in LAYERS_ABOVE_MODELS)]
    assert not offending, "\n".join(offending)


def test_the_import_scan_sees_every_form_of_import(tmp_path: Path) -> None:
    probe = tmp_path / "probe.py"
    probe.write_text("import milling_twin.orchestrator.master\nfrom milling_twin.orchestrator import scenario\n"
                     "from milling_twin import api\nimport importlib\nimportlib.import_module('milling_twin.training')\n")
    names = [name for _, name in _imports(probe)]
    assert {"milling_twin.orchestrator.master", "milling_twin.orchestrator", "milling_twin.api",
            "milling_twin.training"} <= set(names)


def test_a_wheel_installs_only_milling_twin(tmp_path: Path) -> None:
    """Build the wheel from the tracked sources (a copy: setuptools writes build/ beside them) and list it:
    one top-level package, milling_twin, holding every Python file of milling_twin/, models/, orchestrator/."""
    tracked = subprocess.run(["git", "ls-files", "pyproject.toml", "README.md", *PACKAGE_FOLDERS], cwd=REPO_ROOT,
                             capture_output=True, text=True, check=True).stdout.split()
    source = tmp_path / "src"
    for name in tracked:
        if (REPO_ROOT / name).is_file():
            (source / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO_ROOT / name, source / name)
    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(tmp_path / "dist"),
                           str(source)], capture_output=True, text=True, timeout=600)
    if proc.returncode != 0 and "No matching distribution" in proc.stderr:
        pytest.skip(f"the build backend cannot be installed here: {proc.stderr.strip()[-300:]}")
    assert proc.returncode == 0, proc.stderr
    (wheel,) = (tmp_path / "dist").glob("milling_twin-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    top = {n.split("/")[0] for n in names}
    assert top == {"milling_twin", wheel.name.split("-py3")[0].replace(".whl", "") + ".dist-info"}, sorted(top)
    expected = {f"{PACKAGE_FOLDERS[f.split('/')[0]]}/{f.split('/', 1)[1]}" for f in tracked if f.endswith(".py")}
    missing = sorted(expected - set(names))
    assert not missing, f"not in the wheel (add the package to pyproject.toml's packages): {missing}"
    entry_points = zipfile.ZipFile(wheel).read(next(n for n in names if n.endswith("entry_points.txt"))).decode()
    assert "milling-twin = milling_twin.cli:main" in entry_points
