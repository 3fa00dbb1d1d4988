"""Machine code for the calibration's force model: casadi's just-in-time compilation of a Function and of every
derivative of it casadi forms, through the system's C compiler and a cache of the compiled objects.

The slot-forces fit spends most of its time evaluating the cutting-force equations and their derivatives over
hundreds of angles per recording. casadi's virtual machine interprets them; compiled they run several times
faster (``tests/benchmarks/calibrate_slot_speed.py``), to the same numbers (the generated C does the same
operations in the same order; tested to the bit).

* Compiler: ``$CC``, else ``cc``, else ``gcc`` (POSIX systems; elsewhere, when no compiler works and under a
  preloaded AddressSanitizer runtime, the functions stay interpreted and :func:`jit_options` logs why, once per
  process).
* Cache: ``$MILLING_TWIN_JIT_CACHE`` (a folder; ``off`` or an empty value: compile every time), else
  ``$XDG_CACHE_HOME/milling_twin/casadi_jit``, else ``~/.cache/milling_twin/casadi_jit``. The compile step runs
  through ``compile_cache.py``, which keys the object by the source, flags and compiler, so the second fit of the
  same law (in any process) links its objects in milliseconds.
* casadi's temporary sources and libraries go to a temporary folder of the system and are removed after loading.
"""
from __future__ import annotations

import functools
import logging
import os
import shlex
import shutil
import sys
import tempfile
from pathlib import Path

import casadi as ca

from milling_twin.orchestrator.user_cache import cache_folder

__all__ = ["CACHE_ENV", "FLAGS", "cache_root", "find_compiler", "jit_options", "sanitizer_preloaded"]

log = logging.getLogger(__name__)

CACHE_ENV = "MILLING_TWIN_JIT_CACHE"
# -O1: as fast as -O2 on the force model (its straight-line code leaves the optimiser little more to do) and
# compiled in less time
FLAGS = ("-O1",)
_FRONT = Path(__file__).with_name("compile_cache.py")


def cache_root() -> Path | None:
    """The cache folder of compiled objects, or None when the cache is switched off."""
    return cache_folder(CACHE_ENV, "casadi_jit")


def find_compiler() -> str | None:
    """The C compiler's path: ``$CC``, ``cc`` or ``gcc``, the first found; None off POSIX or without one."""
    if os.name != "posix":
        return None
    for name in (os.environ.get("CC"), "cc", "gcc"):
        if name and shutil.which(name):
            return shutil.which(name)
    return None


def sanitizer_preloaded() -> bool:
    """Whether an AddressSanitizer runtime is preloaded (``LD_PRELOAD``): it aborts the process when casadi loads
    its compiler plugin (casadi opens plugins with RTLD_DEEPBIND, which the runtime refuses,
    google/sanitizers#611), so the functions stay interpreted then."""
    return any("asan" in Path(entry).name for entry in os.environ.get("LD_PRELOAD", "").replace(":", " ").split())


def jit_options() -> dict:
    """casadi's options that compile a Function and its derivatives (module text), or ``{}`` (interpreted) when
    no compiler is found, it fails on a probe or a sanitizer runtime is preloaded (logged once per process)."""
    return dict(_checked_options(find_compiler(), cache_root(), sanitizer_preloaded()))


@functools.lru_cache(maxsize=8)
def _checked_options(compiler: str | None, cache: Path | None,
                     sanitized: bool) -> tuple[tuple[str, object], ...]:
    if sanitized:
        log.warning("an AddressSanitizer runtime is preloaded, which refuses casadi's compiler plugin: the force "
                    "model runs in casadi's virtual machine")
        return ()
    if compiler is None:
        log.warning("no C compiler found ($CC, cc, gcc): the force model runs in casadi's virtual machine")
        return ()
    command = compiler if cache is None else " ".join(
        shlex.quote(part) for part in (sys.executable, "-I", str(_FRONT), str(cache), compiler))
    options = {"jit": True, "compiler": "shell", "jit_cleanup": True,
               "jit_options": {"compiler": command, "linker": compiler, "flags": list(FLAGS),
                               "directory": tempfile.gettempdir() + os.sep}}
    try:
        x = ca.SX.sym("x")
        probe = ca.Function("milling_twin_probe", [x], [ca.sin(x) * x], options)
        if abs(float(probe(2.0)) - 2.0 * 0.9092974268256817) > 1e-12:
            raise RuntimeError(f"the compiled probe returned {float(probe(2.0))}")
    except RuntimeError as error:
        log.warning("compiling with %s failed (%s): the force model runs in casadi's virtual machine",
                    compiler, str(error).strip().splitlines()[-1] if str(error).strip() else error)
        return ()
    return tuple(options.items())
