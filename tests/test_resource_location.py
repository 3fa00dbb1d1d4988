"""The resource location of FMI 2 (a file URI) and FMI 3 (a path) decoded by the one copy in
fmus/common/resource_location.c, which ForceNet (its weights) and the Interpolator (its part program) share:
the function itself through ctypes, and both FMUs reading their resources from an awkward folder name."""
from __future__ import annotations

import ctypes
import shutil
import subprocess
import zipfile
from pathlib import Path
from urllib.parse import quote

import pytest

from fmu_helpers import Slave, fmu_dir, require_fmu
from test_forcenet import ODD_NAME, _instantiate_fmi2, _instantiate_fmi3

REPO = Path(__file__).resolve().parents[1]
SOURCE = REPO / "fmus" / "common" / "resource_location.c"


@pytest.fixture(scope="module")
def resource_file(tmp_path_factory):
    compiler = shutil.which("cc") or shutil.which("gcc")
    if compiler is None:
        pytest.skip("no C compiler")
    out = tmp_path_factory.mktemp("resource_location") / "libresource_location.so"
    subprocess.run([compiler, "-std=c99", "-O1", "-Wall", "-Wextra", "-Werror", "-fPIC", "-shared",
                    "-I", str(SOURCE.parent), str(SOURCE), "-o", str(out)], check=True)
    lib = ctypes.CDLL(str(out))
    function = lib.fmu_resource_file
    function.restype = ctypes.c_int
    function.argtypes = [ctypes.c_char_p, ctypes.c_char_p, ctypes.c_char_p, ctypes.c_size_t, ctypes.c_char_p,
                         ctypes.c_size_t]

    def call(location: str, name: str = "weights.bin", size: int = 4096) -> tuple[int, str, str]:
        path, message = ctypes.create_string_buffer(max(size, 1)), ctypes.create_string_buffer(512)
        status = function(location.encode(), name.encode(), path, size, message, 512)
        return status, path.value.decode(), message.value.decode()

    return call


GOOD = {  # location -> the file path
    "file:///a/b%20c/resources/": "/a/b c/resources/weights.bin",
    "file:///a/b%20c/resources": "/a/b c/resources/weights.bin",
    "file:/a/b%2fc/resources": "/a/b/c/resources/weights.bin",  # lower-case hex digits too
    "file://localhost/a/resources/": "/a/resources/weights.bin",
    "/a/dir %41 #x/resources/": "/a/dir %41 #x/resources/weights.bin",  # FMI 3: a path, nothing decoded
    "/a/resources": "/a/resources/weights.bin",
    "relative/resources": "relative/resources/weights.bin",
}
BAD = {  # location -> the reason
    "file://server/share/resources": "is not a local file URI",
    "file:///a/b%zz/resources": "has a bad percent-escape",
    "file:///a/b%2": "has a bad percent-escape",
    "file:///a%00/b/resources": "has a bad percent-escape",  # a NUL would cut the path: /a/weights.bin
}


@pytest.mark.parametrize("location", list(GOOD))
def test_locations_are_decoded(resource_file, location: str) -> None:
    status, path, message = resource_file(location)
    assert (status, path) == (0, GOOD[location]), message


@pytest.mark.parametrize("location", list(BAD))
def test_bad_locations_are_rejected_with_the_reason(resource_file, location: str) -> None:
    status, _, message = resource_file(location)
    assert status == -1 and message == f"the resource location '{location}' {BAD[location]}"


def test_a_path_that_does_not_fit_is_too_long(resource_file) -> None:
    assert resource_file("/a/resources", size=len("/a/resources/weights.bin") + 1)[0] == 0
    status, _, message = resource_file("/a/resources", size=len("/a/resources/weights.bin"))
    assert status == -1 and message.endswith("is too long")


def _unpack(fmu: Path, folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    with zipfile.ZipFile(fmu) as z:
        z.extractall(folder)
    return folder


@pytest.mark.parametrize("version", [3, 2])
def test_the_interpolator_reads_its_program_through_the_shared_decoding(version: int, tmp_path: Path) -> None:
    """The Interpolator's default program comes from resources/program.nc of an FMU unpacked into a folder whose
    name needs percent-encoding in a URI and holds a literal "%41" (which an FMI 3 path keeps)."""
    fmu = require_fmu(fmu_dir() / ("Interpolator.fmu" if version == 3 else "Interpolator_fmi2.fmu"))
    folder = _unpack(fmu, tmp_path / ODD_NAME / "fmu")
    resources = folder / "resources"
    instantiate = _instantiate_fmi3 if version == 3 else _instantiate_fmi2
    good = [str(resources)] if version == 3 else [resources.as_uri(), f"file://localhost{quote(str(resources))}/"]
    for location in good:
        with Slave(fmu, unzipdir=str(folder)) as slave:
            assert instantiate(slave, location), slave.messages
            slave.initialize()
            assert not slave.errors(), (location, slave.messages)
    bad = {"file://server/share/resources": "is not a local file URI"} if version == 2 else {
        str(resources).replace("%41", "A"): "cannot open part program"}
    for location, reason in bad.items():
        with Slave(fmu, unzipdir=str(folder)) as slave:
            assert instantiate(slave, location)
            with pytest.raises(Exception):
                slave.initialize()
            assert reason in slave.last_error() and "parameter 'program' is empty" in slave.last_error()
