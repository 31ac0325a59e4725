"""CPU work that really competes for CPU, at the pace a profile row describes.

A profile row says a cycle takes ``mean`` seconds with ``cpu`` cores (Fig. 3). The workload
therefore burns ``mean * cpu`` CPU-seconds **at a rate of ``cpu`` cores**: split over
``ceil(cpu)`` processes, each spins for its share of every 5 ms slice and sleeps for the rest.
With its share it finishes in ``mean`` seconds of wall time; on a busy node the spinning takes
longer and so does the cycle. This is the simulator's model of a job (``sim.engine``: a job
demands ``cpu_use`` cores for ``work`` seconds and slows down under contention), so reality and
model differ only where reality has more in it (middleware, kubelet, throttling). Without the
pacing a 67m module would run at a full core for a fifteenth of its time: its cycles would be
15 times shorter than its profile says and it would take the CPU in bursts.

The work is counted in the **process's** CPU time, including what its middleware used since
the previous cycle ended (DDS threads receiving and sending, the executor's callbacks): a real
module's profile, measured under its limit, has its middleware in it, so the workload uses its
row's CPU in all, not the row's CPU *plus* its middleware's (15-30m for a 30 Hz module). That
surplus, under a limit set to the row (a Guaranteed pod), was throttled into missing most of
its cycles. The pace is chosen so that the cycle still takes ``mean`` seconds.

Worker processes are forked before ROS starts (forking an rclpy process is not safe) and keep
the GIL away from the ROS executor; each counts its own CPU.
"""

from __future__ import annotations

import math
import multiprocessing
import time
from multiprocessing.pool import Pool

__all__ = ["SLICE_S", "Burner", "burn"]

SLICE_S = 0.005  # pacing slice: short against every cycle time, long against a wake-up


def burn(cpu_seconds: float, rate: float = 1.0) -> float:
    """Use `cpu_seconds` of this process's CPU at `rate` cores (<= 1); returns the wall time.

    Each slice of ``SLICE_S`` spins until the process has used ``rate * SLICE_S`` more and
    sleeps for the rest of the slice. A slice that overran (the thread waited for CPU) is not
    made up by running faster later: a module given less CPU than it demands progresses more
    slowly, as under processor sharing.
    """
    t0, wall0 = time.process_time(), time.monotonic()
    step = max(1e-4, min(rate, 1.0) * SLICE_S)
    used, slice_end = 0.0, wall0
    x = 0
    while used < cpu_seconds:
        target = min(cpu_seconds, used + step)
        while used < target:
            for _ in range(500):
                x += 1
            used = time.process_time() - t0
        slice_end += SLICE_S
        now = time.monotonic()
        if rate < 1.0 and now < slice_end:
            time.sleep(slice_end - now)
        else:
            slice_end = max(slice_end, now)
    return time.monotonic() - wall0


class Burner:
    """Burns a cycle's work at the pace of the module's CPU.

    Up to one core's worth is burnt in the calling thread; more than one core goes to
    ``ceil(cpu)`` worker processes, recreated if one dies (a container's memory limit can kill
    a worker, and a lost task would hang the module).
    """

    def __init__(self, cpu: float) -> None:
        if not cpu > 0.0:
            raise ValueError(f"cpu must be positive, got {cpu}")
        self.cpu = cpu
        self.workers = max(1, math.ceil(cpu - 1e-9))
        self._pool: Pool | None = self._new_pool() if self.workers > 1 else None
        self._since = time.process_time()  # the process's CPU when the last cycle's work ended

    def _new_pool(self) -> Pool:
        return multiprocessing.get_context("fork").Pool(self.workers)

    def run(self, seconds: float) -> float:
        """Work that takes `seconds` with `cpu` cores: ``seconds * cpu`` CPU-seconds, less what
        the process used since the last cycle, spread over `seconds` (at most `cpu` cores);
        returns the wall time until all of it is done."""
        t0 = time.monotonic()
        between = time.process_time() - self._since
        try:
            return self._run(seconds, max(0.0, seconds * self.cpu - between) / self.workers, t0)
        finally:
            self._since = time.process_time()

    def _run(self, seconds: float, share: float, t0: float) -> float:
        rate = min(1.0, share / seconds) if seconds > 0 else 1.0
        if self._pool is None:
            burn(share, rate)
        else:
            try:
                self._pool.starmap_async(burn, [(share, rate)] * self.workers, chunksize=1).get(
                    timeout=60 + 100 * seconds
                )
            except multiprocessing.TimeoutError:
                self._pool.terminate()
                self._pool = self._new_pool()
        # the row's time even when the middleware already used the row's CPU (nothing to spin)
        left = t0 + seconds - time.monotonic()
        if left > 0:
            time.sleep(left)
        return time.monotonic() - t0

    def close(self) -> None:
        if self._pool is not None:
            self._pool.terminate()
