"""The wheel's build step (the project's metadata is in pyproject.toml): every built FMU and the stepper library
go into the package (milling_twin/fmus/, milling_twin/stepper/) and the wheel gets the platform tag they need
(buildtools/wheel_files.py). Nothing is compiled here, and the editable install (`pip install -e .`) copies
nothing: `make wheel` builds the FMUs with CMake first. docs/packaging.md."""
from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

from setuptools import Distribution, setup
from setuptools.command.bdist_wheel import bdist_wheel
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
sys.path.insert(0, str(ROOT))

from buildtools.wheel_files import PACKAGE_FMUS, PACKAGE_STEPPER, WheelFiles, select  # noqa: E402


def _editable(command: build_py | bdist_wheel) -> bool:
    return "editable_wheel" in command.distribution.command_obj


class NativeDistribution(Distribution):
    """A distribution whose wheel carries native files (no extension modules), so that the package installs into
    platlib, at the root of the wheel."""

    native = False

    def has_ext_modules(self) -> bool:
        return self.native or super().has_ext_modules()


class BuildPy(build_py):
    """build_py, then the FMUs and the stepper library copied into the built package."""

    def run(self) -> None:
        super().run()
        if self.editable_mode or _editable(self):
            return
        files = select(ROOT, os.environ)
        if not files.native:
            return
        fmus, stepper = Path(self.build_lib) / PACKAGE_FMUS, Path(self.build_lib) / PACKAGE_STEPPER
        for folder in (fmus, stepper):
            shutil.rmtree(folder, ignore_errors=True)
            folder.mkdir(parents=True)
        for fmu in files.fmus:
            shutil.copyfile(fmu, fmus / fmu.name)
        assert files.stepper is not None
        shutil.copyfile(files.stepper, stepper / files.stepper.name)


class BdistWheel(bdist_wheel):
    """A native wheel, py3-none-manylinux_<glibc>_<arch>, when it carries the stepper library."""

    files: WheelFiles | None = None

    def run(self) -> None:
        # chosen here, not in finalize_options: the metadata steps (also of the editable install) finalize this
        # command too, and need no FMUs
        self.files = select(ROOT, os.environ)
        self.distribution.native = self.files.native  # type: ignore[attr-defined]
        self.root_is_pure = not self.files.native
        super().run()

    def get_tag(self) -> tuple[str, str, str]:
        if self.files is None or not self.files.native:
            return super().get_tag()
        return "py3", "none", self.files.platform_tag()


# setuptools' own build/ would land in the CMake build tree: keep it in one folder of it
setup(distclass=NativeDistribution, cmdclass={"build_py": BuildPy, "bdist_wheel": BdistWheel},
      options={"build": {"build_base": "build/python-wheel"}})
