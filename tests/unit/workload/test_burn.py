"""The workload's CPU burner plays a profile row at its pace: `cpu` cores for `mean` seconds."""

from __future__ import annotations

import os
import time

import pytest

from fogfleet.workload import burn as burn_module
from fogfleet.workload.burn import Burner, burn


def _cpu_and_wall(fn: object, *args: float) -> tuple[float, float]:
    """CPU seconds (this process's by ``process_time``, exact, as the burner counts it; its
    reaped children's by ``os.times``) and wall seconds of one call. ``os.times`` alone counts
    in 10 ms clock ticks, so 0.1 s of CPU could read as 0.09."""
    t, cpu0 = os.times(), time.process_time()
    wall0 = time.monotonic()
    fn(*args)  # type: ignore[operator]
    wall = time.monotonic() - wall0
    after, cpu = os.times(), time.process_time() - cpu0
    cpu += (after.children_user - t.children_user) + (after.children_system - t.children_system)
    return cpu, wall


def test_a_fractional_core_takes_the_rows_wall_time_and_only_its_share_of_cpu() -> None:
    # 0.2 s with 0.25 cores: 0.05 CPU-seconds spread over 0.2 s, not a 0.05 s burst
    cpu, wall = _cpu_and_wall(Burner(0.25).run, 0.2)
    assert 0.19 <= wall <= 2.0, wall  # never sooner; later only on a busy machine
    assert 0.04 <= cpu <= 0.08, cpu


def test_a_whole_core_burns_without_sleeping(monkeypatch: pytest.MonkeyPatch) -> None:
    naps: list[float] = []
    monkeypatch.setattr(time, "sleep", naps.append)
    mine = time.thread_time()
    cpu, wall = _cpu_and_wall(burn, 0.1, 1.0)
    # the burner counts its process's CPU: what another thread of this process used meanwhile
    # (a thread an earlier test left, waking up) ends the burn that much sooner in wall time
    # (test-stress once: 0.100012 s of CPU in 0.099958 s)
    others = max(cpu - (time.thread_time() - mine), 0.0)
    assert naps == [] and cpu >= 0.095 and wall + others >= 0.1, (naps, cpu, wall, others)


@pytest.mark.integration
def test_more_than_a_core_goes_to_worker_processes() -> None:
    burner = Burner(1.5)
    try:
        assert burner.workers == 2
        wall = burner.run(0.2)  # 0.3 CPU-seconds, 0.15 in each of two processes at 0.75 cores
        assert 0.19 <= wall <= 3.0, wall
    finally:
        burner.close()


def test_a_burner_needs_a_positive_cpu() -> None:
    with pytest.raises(ValueError, match="cpu must be positive"):
        Burner(0.0)


def test_cpu_the_process_used_since_the_last_cycle_is_part_of_the_next_cycles_work() -> None:
    """A module's middleware (DDS threads, callbacks) runs between cycles; its CPU is part of
    the row's, so the burner spins only for the rest, still over the row's wall time."""
    burner = Burner(0.5)
    burner.run(0.01)
    burn(0.03)  # the middleware's CPU between two cycles
    cpu, wall = _cpu_and_wall(burner.run, 0.1)  # 0.05 CPU-seconds in all, 0.03 already used
    assert 0.095 <= wall <= 2.0, wall
    assert 0.01 <= cpu <= 0.035, cpu


def test_a_cycle_lasts_the_rows_time_even_when_the_middleware_used_all_its_cpu() -> None:
    burner = Burner(0.05)
    burn(0.02)  # more than the next cycle's 0.05 s x 0.05 cores
    cpu, wall = _cpu_and_wall(burner.run, 0.05)
    assert wall >= 0.049 and cpu < 0.01, (cpu, wall)


class _OversleepingClock:
    """The burner's clocks on a host where every nap oversleeps by 20 ms but spinning gets the
    CPU: each CPU reading costs 0.1 ms of CPU and wall time, each nap its length + 20 ms. The
    test's verdict then depends on the burner's pacing alone, not on how busy the machine is
    (on a real host too busy to give it the CPU, no pacing can catch up)."""

    def __init__(self) -> None:
        self.cpu = self.wall = 0.0

    def process_time(self) -> float:
        self.cpu += 1e-4
        self.wall += 1e-4
        return self.cpu

    def monotonic(self) -> float:
        return self.wall

    def sleep(self, seconds: float) -> None:
        self.wall += seconds + 0.02


def test_progress_lost_to_late_wake_ups_is_made_up(monkeypatch: pytest.MonkeyPatch) -> None:
    """Every nap oversleeps by 20 ms: the work keeps its pace instead of adding the delay to
    every other slice (0.1 s of work at 0.25 cores took about 0.26 s before it did)."""
    clock = _OversleepingClock()
    monkeypatch.setattr(burn_module, "time", clock)
    wall = burn(0.025, 0.25)
    assert clock.cpu == pytest.approx(0.025, abs=2e-4)
    assert 0.1 <= wall <= 0.13, wall
