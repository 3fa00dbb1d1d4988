"""How many cases go into one task sent to a cluster: enough that the engine's cost per task stays small, few enough
that every worker stays busy to the end.

A dask task costs the scheduler, the client and the worker's event loop a few milliseconds of CPU each, on the same
cores that run the cases. The 240 cases of the stability map (~40 ms each: 0.2 s at 10 us) ran 1.25 to 1.44 times
faster on 2 workers of a 2-core machine than serially with one case per task, 1.68 to 1.78 times with four and
1.66 to 1.86 with eight (a one-off comparison in one process, the cases alone; the benchmark of the whole study:
docs/studies.md#measured). Case times are not known before the first cases finish, so :class:`BatchSizer` starts
with one case per task and sizes later tasks from the median case time measured so far:

    size = round(TASK_SECONDS / median case time), within 1 .. MAX_CASES,
           and at most ceil(remaining / (2 * slots)) so that the last tasks are small and end together.
"""
from __future__ import annotations

import math
import statistics
from dataclasses import dataclass, field

__all__ = ["MAX_CASES", "TASK_SECONDS", "BatchSizer"]

TASK_SECONDS = 0.25  # a task's aim: well above the engine's milliseconds, well below a progress bar's patience
MAX_CASES = 32  # a lost task (a worker killed) reruns at most this many cases


@dataclass
class BatchSizer:
    """Sizes the tasks of one dispatch; ``slots``: the cases the cluster runs at once (its worker threads)."""

    slots: int
    task_seconds: float = TASK_SECONDS
    max_cases: int = MAX_CASES
    _times: list[float] = field(default_factory=list)

    def record(self, wall_time: float) -> None:
        """A finished case's own time on its worker (s); NaN or negative (a lost case) is ignored."""
        if math.isfinite(wall_time) and wall_time >= 0:
            self._times.append(wall_time)

    def size(self, remaining: int) -> int:
        """The number of cases of the next task, ``remaining`` cases left to submit (>= 1)."""
        if remaining <= 0:
            raise ValueError(f"remaining = {remaining}: nothing to size")
        if not self._times:
            return 1
        per_case = statistics.median(self._times)
        wanted = self.max_cases if per_case <= 0 else round(self.task_seconds / per_case)
        tail = math.ceil(remaining / (2 * max(1, self.slots)))
        return max(1, min(wanted, self.max_cases, tail, remaining))
