"""numpy's and scipy's bundled OpenBLAS on one thread for a block of small dense linear algebra.

Both the semi-discretization's monodromy matrices (:mod:`.stability`, sizes 12 to ~300) and the
Levenberg-Marquardt steps of the calibration (QR of 1,500 x 34 on the slot forces) are too small for BLAS threads
to help, and OpenBLAS's threads spin-wait between calls: on a busy 2-core machine one stability speed took 10 to
100 times longer with two threads, one QR 10 to 25 times. Nothing happens for another BLAS.
"""
from __future__ import annotations

import contextlib
import ctypes
import functools
import threading
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

__all__ = ["one_blas_thread", "openblas_thread_controls"]


class OneBlasThread:
    """The switch: ``with one_blas_thread(): ...``.

    OpenBLAS's thread count belongs to the process, so the switch is counted: the first of any number of
    concurrent users (threads of a study's worker, say) saves the count and sets one thread, the last restores it.
    Without the count, two overlapping users restoring in the wrong order would leave the process on one thread."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._users = 0
        self._saved: list[int] = []

    @contextlib.contextmanager
    def __call__(self) -> Iterator[None]:
        controls = openblas_thread_controls()
        with self._lock:
            if self._users == 0:
                self._saved = [get() for get, _ in controls]
                for _, set_ in controls:
                    set_(1)
            self._users += 1
        try:
            yield
        finally:
            with self._lock:
                self._users -= 1
                if self._users == 0:
                    for (_, set_), threads in zip(controls, self._saved):
                        set_(threads)


# One per process, like the thread count it guards.
one_blas_thread = OneBlasThread()


@functools.lru_cache(maxsize=1)
def openblas_thread_controls() -> tuple[tuple[Callable[[], int], Callable[[int], None]], ...]:
    """(get, set) of the thread count of every OpenBLAS that numpy and scipy bundle (found once per process)."""
    import scipy

    controls = []
    for package in (np, scipy):
        folder = Path(package.__file__).resolve().parent.parent / f"{package.__name__}.libs"
        for library in sorted(folder.glob("lib*openblas*.so*")):
            try:
                handle = ctypes.CDLL(str(library))
            except OSError:
                continue
            for prefix, suffix in (("scipy_openblas", "64_"), ("scipy_openblas", ""), ("openblas", "64_"),
                                   ("openblas", "")):
                get = getattr(handle, f"{prefix}_get_num_threads{suffix}", None)
                set_ = getattr(handle, f"{prefix}_set_num_threads{suffix}", None)
                if get is not None and set_ is not None:
                    get.restype, set_.argtypes = ctypes.c_int, [ctypes.c_int]
                    controls.append((get, set_))
                    break
    return tuple(controls)
