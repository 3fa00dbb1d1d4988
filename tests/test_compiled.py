"""The force model compiled to machine code (orchestrator/calibrate/compiled.py) and the cache of compiled objects
(compile_cache.py): a source compiled once is copied the next time, whatever its temporary names; other flags or
another source compile again; a cache that cannot be written still compiles; no compiler leaves the functions
interpreted with a warning."""
from __future__ import annotations

import logging
import os
import stat
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from milling_twin.orchestrator.calibrate import compiled
from milling_twin.orchestrator.calibrate.compile_cache import cached_compile

SOURCE = "double twice(double x) { return 2 * x; }\n"


@pytest.fixture(autouse=True)
def fresh_probe():
    """jit_options probes (and warns) once per process and set-up: each test starts without that memory."""
    compiled._checked_options.cache_clear()
    yield
    compiled._checked_options.cache_clear()


needs_jit = pytest.mark.skipif(compiled.sanitizer_preloaded(),
                               reason="a preloaded AddressSanitizer runtime refuses casadi's compiler plugin")


@pytest.fixture
def counting_compiler(tmp_path: Path) -> tuple[str, Path]:
    """A compiler that counts its calls in a file, then runs the system's."""
    real = compiled.find_compiler()
    if real is None:
        pytest.skip("no C compiler on this machine")
    calls = tmp_path / "calls"
    script = tmp_path / "counting-cc"
    script.write_text(f'#!/bin/sh\necho "$@" >> "{calls}"\nexec "{real}" "$@"\n')
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    return str(script), calls


def compile_once(compiler: str, cache: Path, folder: Path, name: str, source: str = SOURCE,
                 flags: tuple[str, ...] = ("-O1",)) -> Path:
    (folder / f"{name}.c").write_text(source)
    output = folder / f"{name}.o"
    assert cached_compile(cache, compiler, [*flags, "-fPIC", "-c", str(folder / f"{name}.c"), "-o", str(output)]) == 0
    return output


def test_a_source_compiled_once_is_copied_from_the_cache_whatever_its_temporary_names(counting_compiler, tmp_path):
    compiler, calls = counting_compiler
    cache = tmp_path / "cache"
    first = compile_once(compiler, cache, tmp_path, "jit_tmpA")
    second = compile_once(compiler, cache, tmp_path, "jit_tmpB")
    assert len(calls.read_text().splitlines()) == 1
    assert first.read_bytes() == second.read_bytes()
    assert [p.suffix for p in cache.iterdir()] == [".o"]  # no partial file left beside it
    compile_once(compiler, cache, tmp_path, "jit_tmpC", flags=("-O2",))
    compile_once(compiler, cache, tmp_path, "jit_tmpD", source=SOURCE.replace("2 * x", "3 * x"))
    assert len(calls.read_text().splitlines()) == 3
    assert len(list(cache.iterdir())) == 3


def test_the_link_and_a_failed_compile_are_not_cached(counting_compiler, tmp_path):
    compiler, calls = counting_compiler
    cache = tmp_path / "cache"
    (tmp_path / "bad.c").write_text("this is not C\n")
    assert cached_compile(cache, compiler, ["-c", str(tmp_path / "bad.c"), "-o", str(tmp_path / "bad.o")]) != 0
    assert not cache.exists() or not any(cache.iterdir())
    obj = compile_once(compiler, cache, tmp_path, "good")
    for _ in range(2):
        assert cached_compile(cache, compiler, [str(obj), "-o", str(tmp_path / "good.so"), "-shared"]) == 0
    assert len(calls.read_text().splitlines()) == 4  # bad, good, two links


def test_a_cache_that_cannot_be_written_still_compiles(counting_compiler, tmp_path, capfd):
    compiler, _ = counting_compiler
    blocked = tmp_path / "a-file"
    blocked.write_text("")
    obj = compile_once(compiler, blocked / "cache", tmp_path, "x")
    assert obj.stat().st_size > 0
    assert "not cached" in capfd.readouterr().err


@needs_jit
def test_compiled_functions_and_their_derivatives_run_through_the_cache(tmp_path, monkeypatch):
    if compiled.find_compiler() is None:
        pytest.skip("no C compiler on this machine")
    monkeypatch.setenv(compiled.CACHE_ENV, str(tmp_path / "cache"))
    options = compiled.jit_options()
    assert options["jit"] is True
    x = ca.SX.sym("x", 2)
    f = ca.Function("f", [x], [ca.exp(x[0]) * ca.sin(x[1])], options)
    interpreted = ca.Function("f", [x], [ca.exp(x[0]) * ca.sin(x[1])])
    y = ca.MX.sym("y", 2)
    jacobians = [ca.Function("j", [y], [ca.jacobian(g(y), y)]) for g in (f, interpreted)]
    assert np.array_equal(np.asarray(jacobians[0]([0.3, 1.1])), np.asarray(jacobians[1]([0.3, 1.1])))
    objects = sorted(p.name for p in (tmp_path / "cache").iterdir())
    assert len(objects) >= 3  # the probe, the function and its derivative
    # the same again (a later fit): every object from the cache, none added
    again = ca.Function("f", [x], [ca.exp(x[0]) * ca.sin(x[1])], compiled.jit_options())
    ca.Function("j", [y], [ca.jacobian(again(y), y)])([0.3, 1.1])
    assert sorted(p.name for p in (tmp_path / "cache").iterdir()) == objects


def test_without_a_compiler_the_functions_stay_interpreted_with_a_warning(monkeypatch, caplog):
    monkeypatch.delenv("LD_PRELOAD", raising=False)  # the sanitizer stage's runtime is checked first
    monkeypatch.setattr(compiled, "find_compiler", lambda: None)
    with caplog.at_level(logging.WARNING):
        assert compiled.jit_options() == {}
    assert "no C compiler found" in caplog.text


@needs_jit
def test_a_compiler_that_fails_leaves_the_functions_interpreted(tmp_path, monkeypatch, caplog):
    broken = tmp_path / "broken-cc"
    broken.write_text("#!/bin/sh\nexit 1\n")
    broken.chmod(0o755)
    monkeypatch.setattr(compiled, "find_compiler", lambda: str(broken))
    with caplog.at_level(logging.WARNING):
        assert compiled.jit_options() == {}
    assert f"compiling with {broken} failed" in caplog.text


def test_under_a_preloaded_sanitizer_the_functions_stay_interpreted(monkeypatch, caplog):
    monkeypatch.setenv("LD_PRELOAD", "/usr/lib/gcc/x86_64-linux-gnu/12/libasan.so /usr/lib/libubsan.so")
    assert compiled.sanitizer_preloaded()
    with caplog.at_level(logging.WARNING):
        assert compiled.jit_options() == {}
    assert "AddressSanitizer" in caplog.text
    monkeypatch.setenv("LD_PRELOAD", "libfaketime.so")
    assert not compiled.sanitizer_preloaded()


def test_the_cache_folder_follows_the_environment(monkeypatch, tmp_path):
    monkeypatch.setenv(compiled.CACHE_ENV, "off")
    assert compiled.cache_root() is None
    monkeypatch.delenv(compiled.CACHE_ENV)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert compiled.cache_root() == tmp_path / "milling_twin" / "casadi_jit"
    assert os.fspath(compiled.cache_root()).startswith(os.fspath(tmp_path))
