"""CPU work that really competes for CPU: busy loops measured in CPU time, in worker processes.

A profile row says a cycle takes ``mean`` seconds with ``cpu`` cores (Fig. 3). The work is
therefore ``mean * cpu`` CPU-seconds, split over ceil(cpu) processes; a container throttled to
fewer cores (its CFS quota, or a busy node) finishes it later in wall time, as the real
module would. Worker processes are forked before ROS starts (forking an rclpy process is not
safe) and keep the GIL away from the ROS executor.
"""

from __future__ import annotations

import multiprocessing
import time
from multiprocessing.pool import Pool

__all__ = ["Burner", "burn"]


def burn(cpu_seconds: float) -> float:
    """Spin until this thread has used `cpu_seconds` of CPU; returns the wall time it took."""
    t0, wall0 = time.thread_time(), time.monotonic()
    x = 0
    while time.thread_time() - t0 < cpu_seconds:
        for _ in range(2000):
            x += 1
    return time.monotonic() - wall0


class Burner:
    def __init__(self, workers: int) -> None:
        self.workers = max(1, workers)
        self._pool: Pool = multiprocessing.get_context("fork").Pool(self.workers)

    def run(self, cpu_seconds: float) -> float:
        """Burn `cpu_seconds` across the workers; the wall time until all are done."""
        t0 = time.monotonic()
        share = cpu_seconds / self.workers
        self._pool.map(burn, [share] * self.workers, chunksize=1)
        return time.monotonic() - t0

    def close(self) -> None:
        self._pool.terminate()
