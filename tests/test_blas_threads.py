"""The one-thread switch of numpy's and scipy's bundled OpenBLAS (models/blas_threads.py): counted for overlapping
users, the count restored; and the Levenberg-Marquardt solver's iterations inside it."""
from __future__ import annotations

import threading

import casadi as ca
import numpy as np
import pytest

from milling_twin.models.blas_threads import one_blas_thread, openblas_thread_controls
from milling_twin.orchestrator.calibrate.lsq import LeastSquaresProblem, LeastSquaresSolver


def test_the_one_thread_blas_switch_holds_for_overlapping_users_and_restores_the_count():
    controls = openblas_thread_controls()
    if not controls:
        pytest.skip("numpy and scipy use another BLAS than their bundled OpenBLAS: nothing to switch")
    before = [get() for get, _ in controls]
    inside: list[list[int]] = []
    barrier = threading.Barrier(3)

    def user() -> None:
        with one_blas_thread():
            barrier.wait()  # all three inside at once; then they leave in any order
            inside.append([get() for get, _ in controls])

    threads = [threading.Thread(target=user) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert inside == [[1] * len(controls)] * 3
    assert [get() for get, _ in controls] == before


def test_levenberg_marquardt_iterates_on_one_blas_thread(monkeypatch) -> None:
    """The iterations' small QR factorings on one thread (OpenBLAS's spinning threads made them 10 to 25 times
    slower on a busy machine), and the caller's thread count back afterwards."""
    controls = openblas_thread_controls()
    if not controls:
        pytest.skip("numpy and scipy use another BLAS than their bundled OpenBLAS: nothing to switch")
    x, p = ca.MX.sym("x", 2), ca.MX.sym("p", 0)
    t = np.linspace(0.0, 1.0, 50)
    problem = LeastSquaresProblem(x, p, x[0] * ca.DM(t) + x[1] * ca.DM(t ** 2) - ca.DM(3 * t - t ** 2),
                                  ca.MX(0, 1), np.full(2, -10.0), np.full(2, 10.0), 2,
                                  algorithm="levenberg-marquardt")
    seen: list[list[int]] = []
    original = LeastSquaresSolver._levenberg_marquardt

    def spy(self, *args, **kwargs):  # type: ignore[no-untyped-def]
        seen.append([get() for get, _ in controls])
        return original(self, *args, **kwargs)

    monkeypatch.setattr(LeastSquaresSolver, "_levenberg_marquardt", spy)
    before = [get() for get, _ in controls]
    for _, set_ in controls:  # two threads, as on a 2-core machine, whatever this one has
        set_(2)
    raised = [get() for get, _ in controls]
    try:
        if raised == [1] * len(controls):
            pytest.skip("this OpenBLAS runs one thread at most: nothing to tell apart")
        outcome = LeastSquaresSolver(problem).solve(np.zeros(2), np.zeros(0))
        after = [get() for get, _ in controls]
    finally:
        for (_, set_), threads in zip(controls, before):
            set_(threads)
    assert outcome.converged and np.allclose(outcome.x, [3.0, -1.0]), outcome
    assert seen == [[1] * len(controls)], seen
    assert after == raised
