"""CPU work that really competes for CPU, at the pace a profile row describes.

A profile row says a cycle takes ``mean`` seconds with ``cpu`` cores (Fig. 3). The workload
therefore burns ``mean * cpu`` CPU-seconds **at a rate of ``cpu`` cores**: split over
``ceil(cpu)`` processes, each spins for its share of every 5 ms slice and sleeps for the
rest. With its share it finishes in ``mean`` seconds of wall time; on a busy node the
spinning takes longer and so does the cycle. This is the simulator's model of a job
(``sim.engine``: a job demands ``cpu_use`` cores for ``work`` seconds and slows down under
contention), so reality and model differ only where reality has more in it (middleware,
kubelet, throttling). Without the pacing a 67m module would run at a full core for a
fifteenth of its time: its cycles would be 15 times shorter than its profile says and it
would take the CPU in bursts.

Progress lost to a late wake-up is made up in the next slices (``burn``): a program that gets
its CPU late computes on; only a node too busy to give the CPU back makes the cycle longer.

The work is counted in the **process's** CPU time, including what its middleware used since
the previous cycle ended (DDS threads receiving and sending, the executor's callbacks): a real
module's profile, measured under its limit, has its middleware in it, so the workload uses its
row's CPU in all, not the row's CPU *plus* its middleware's (15-30m for a 30 Hz module). The
pace is chosen so that the cycle still takes ``mean`` seconds.

Worker processes are forked before ROS starts (forking an rclpy process is not safe) and keep
the GIL away from the ROS executor; each counts its own CPU. (Burning a fractional core in a
worker too was tried: the pool's own threads and pipes cost the module process more CPU than
the GIL it freed, and the time a cycle spent outside its work did not shrink.)
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

    By the end of the k-th slice of ``SLICE_S`` the process has used ``k * rate * SLICE_S``:
    each slice spins up to that mark and sleeps for the rest. A slice that starts late (the
    thread woke up late) spins longer, so a wake-up delay of a few milliseconds costs the cycle
    nothing while the CPU is there to make it up, as a program computes on when it gets its
    CPU late. On a node too busy to give it, the spinning cannot catch up and the cycle takes
    longer (processor sharing, the simulator's job model).
    """
    t0, wall0 = time.process_time(), time.monotonic()
    rate = min(rate, 1.0)
    used, slices, x = 0.0, 0, 0
    while used < cpu_seconds:
        # the slice we are in (a late wake-up skips the slices it slept through)
        slices = max(slices + 1, math.ceil((time.monotonic() - wall0) / SLICE_S + 1e-9))
        target = min(cpu_seconds, max(used + 1e-4, slices * rate * SLICE_S))
        while used < target:
            for _ in range(500):
                x += 1
            used = time.process_time() - t0
        if rate < 1.0:
            left = wall0 + slices * SLICE_S - time.monotonic()
            if left > 0 and used < cpu_seconds:
                time.sleep(left)
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
