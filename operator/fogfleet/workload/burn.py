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
    """One core's worth of work is burnt in the calling thread (time.thread_time counts only
    its own CPU, so sharing the GIL with the ROS executor does not change the work); more
    than one core's worth goes to worker processes, recreated if one dies (a container's
    memory limit can kill a worker, and a lost task would hang the module)."""

    def __init__(self, workers: int) -> None:
        self.workers = max(1, workers)
        self._pool: Pool | None = self._new_pool() if self.workers > 1 else None

    def _new_pool(self) -> Pool:
        return multiprocessing.get_context("fork").Pool(self.workers)

    def run(self, cpu_seconds: float) -> float:
        """Burn `cpu_seconds` across the workers; the wall time until all are done."""
        t0 = time.monotonic()
        if self._pool is None:
            burn(cpu_seconds)
            return time.monotonic() - t0
        share = cpu_seconds / self.workers
        try:
            self._pool.map_async(burn, [share] * self.workers, chunksize=1).get(
                timeout=60 + 100 * cpu_seconds
            )
        except multiprocessing.TimeoutError:
            self._pool.terminate()
            self._pool = self._new_pool()
        return time.monotonic() - t0

    def close(self) -> None:
        if self._pool is not None:
            self._pool.terminate()
