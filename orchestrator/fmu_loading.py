"""fmpy's FMU2Slave / FMU3Slave, with the FMI function table introspected once per class.

fmpy binds each FMI function of an FMU's shared library in ``_loadFunctions``: for every
``fmi2*``/``fmi3*`` method of the class it calls ``inspect.signature`` and turns the annotations into
ctypes ``argtypes``/``restype``. That table depends only on the class, yet fmpy rebuilds it for every
instance: about 34 (FMI 2) to 100 (FMI 3) signatures, 1-3 ms per FMU, more than a whole native run
of the UMich scenarios takes (docs/performance.md). The classes here compute the table with
fmpy's own rules the first time a class is loaded and then only bind the library's functions.
Everything else (loading the library, instantiating, the convenience calls, error handling) is
fmpy's; ``tests/test_fmu_loading.py`` checks that the bound functions equal fmpy's, name by name.

Loading a binary, fmpy changes the working directory to the binary's folder and changes it back only
when the library loads: here the working directory is always restored, and a binary that cannot be
loaded (not a shared library, another platform, a missing FMI function) raises :class:`FmuLoadError`
naming the FMU and the binary, ``FMU <model> (instance <name>): its binary <path> cannot be loaded:
<reason>``. Loads are serialised by a lock, so that threads loading FMUs do not change each other's
working directory.
"""
from __future__ import annotations

import contextlib
import ctypes
import inspect
import os
import re
import threading
import types
import typing
from collections.abc import Iterator
from typing import Any

from fmpy.fmi2 import FMU2Slave as _FmpyFMU2Slave
from fmpy.fmi3 import FMU3Slave as _FmpyFMU3Slave

__all__ = ["FMU2Slave", "FMU3Slave", "FmuLoadError", "function_table"]

# (method name, argument names, argtypes, restype) of every FMI function a class binds
FunctionTable = tuple[tuple[str, tuple[str, ...], tuple[Any, ...], Any], ...]

_tables: dict[type, FunctionTable] = {}
_lock = threading.Lock()
_loading_lock = threading.Lock()  # fmpy changes the process's working directory while it loads a binary


class FmuLoadError(ValueError):
    """An FMU whose binary cannot be loaded (the FMU's problem, not the run's)."""


def _binary(kwargs: dict[str, Any], fmi3: bool, message: str) -> tuple[str, str]:
    """The shared library fmpy tried to load and why it failed, from fmpy's ``message`` (else as fmpy finds it)."""
    from fmpy import platform, platform_tuple, sharedLibraryExtension

    for pattern in (rf"Failed to load shared library (.+?{re.escape(sharedLibraryExtension)})\. (.*)",
                    r"Cannot find shared library (.+)\.()"):
        match = re.fullmatch(pattern, message, re.DOTALL)
        if match:
            binary, reason = match.group(1), match.group(2)
            reason = reason[len(binary) + 2:] if reason.startswith(f"{binary}: ") else reason
            return binary, reason or "the file does not exist"
    if kwargs.get("libraryPath"):
        return str(kwargs["libraryPath"]), message
    binary = os.path.abspath(os.path.join(str(kwargs.get("unzipDirectory", "")), "binaries",
                                          platform_tuple if fmi3 else platform,
                                          f"{kwargs.get('modelIdentifier')}{sharedLibraryExtension}"))
    return binary, message.replace(f"{binary}: ", "")


@contextlib.contextmanager
def _loading(kwargs: dict[str, Any], fmi3: bool) -> Iterator[None]:
    """Around fmpy's constructor: the working directory restored, a load failure made an FmuLoadError."""
    with _loading_lock:
        cwd = os.getcwd()
        try:
            yield
        except Exception as exc:  # fmpy raises a bare Exception; ctypes an OSError or AttributeError
            binary, reason = _binary(kwargs, fmi3, str(exc))
            raise FmuLoadError(f"FMU {kwargs.get('modelIdentifier')} (instance {kwargs.get('instanceName')}): "
                               f"its binary {binary} cannot be loaded: {reason}") from exc
        finally:
            if os.getcwd() != cwd:
                os.chdir(cwd)


def function_table(fmu: Any) -> FunctionTable:
    """The FMI functions ``fmu``'s class binds, as fmpy's ``_loadFunctions`` derives them (cached per class)."""
    cls = type(fmu)
    table = _tables.get(cls)
    if table is None:
        prefix = "fmi3" if cls.__name__.startswith("FMU3") else "fmi2"
        rows = []
        for name, _ in inspect.getmembers(fmu):
            if not name.startswith(prefix):
                continue
            signature = inspect.signature(getattr(fmu, name))
            argnames = tuple(p.name for p in signature.parameters.values())
            argtypes = tuple(typing.get_args(p.annotation)[0] if isinstance(p.annotation, types.UnionType)
                             else p.annotation for p in signature.parameters.values())
            restype = signature.return_annotation
            restype = ctypes.c_char_p if restype is bytes else ctypes.c_int if restype is int else restype
            rows.append((name, argnames, argtypes, restype))
        table = tuple(rows)
        with _lock:
            _tables.setdefault(cls, table)
    return table


def _bind(fmu: Any) -> None:
    for name, argnames, argtypes, restype in function_table(fmu):
        c_function = getattr(fmu.dll, name)
        c_function.argnames = list(argnames)
        c_function.argtypes = list(argtypes)
        c_function.restype = restype
        fmu._functions[name] = c_function


class FMU2Slave(_FmpyFMU2Slave):
    """fmpy's FMU2Slave; the FMI function table is introspected once per class (see the module doc)."""

    def __init__(self, **kwargs: Any) -> None:
        with _loading(kwargs, fmi3=False):
            super().__init__(**kwargs)

    def _loadFunctions(self) -> None:
        _bind(self)


class FMU3Slave(_FmpyFMU3Slave):
    """fmpy's FMU3Slave; the FMI function table is introspected once per class (see the module doc)."""

    def __init__(self, **kwargs: Any) -> None:
        with _loading(kwargs, fmi3=True):
            super().__init__(**kwargs)

    def _loadFunctions(self) -> None:
        _bind(self)
