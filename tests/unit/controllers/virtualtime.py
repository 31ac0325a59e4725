"""Run a coroutine on an event loop whose clock is virtual (looptime, by kopf's author).

``asyncio.sleep``, ``loop.call_later`` and ``loop.time()`` then follow a clock that jumps
straight to the next timer whenever the loop has nothing else to do: a test of debouncing,
back-off or ``max_wait`` sees exactly the delays it asked for, on any machine and under any
load, and takes no real time waiting. Real I/O and threads still run in real time.
"""

from __future__ import annotations

import asyncio
from collections.abc import Coroutine
from typing import Any, TypeVar

import looptime

T = TypeVar("T")


def run_in_virtual_time(main: Coroutine[Any, Any, T]) -> T:
    """``asyncio.run(main)`` on a loop whose time starts at 0 and only moves by its timers."""
    with asyncio.Runner(loop_factory=lambda: looptime.new_event_loop(start=0.0)) as runner:
        return runner.run(main)
