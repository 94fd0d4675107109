"""The display yields the CPU to the run: the UI thread at a lower priority (Linux).

Measured on the bench's two shared cores, a run under `rig tui` takes the sim
(~40 % of a core), the runner (~30–50 %) and the display (~30 %); when other work
fills the machine, the run's processes must win. On Linux `nice` is per thread,
and a thread or process inherits its creator's: so `Spawner`'s thread is made
first, at normal priority, and starts every process a run needs (`sim serve`,
the runner); then `lower_this_thread` lowers only the UI thread. Elsewhere
(per-process nice) nothing is lowered.
"""

from __future__ import annotations

import os
import sys
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import TypeVar

T = TypeVar("T")
DISPLAY_NICE = 10  # `rig tui`'s UI thread: ~1/10 of a run process's CPU share when contended


class Spawner:
    """One thread at the priority of its creator that runs `call(fn)` and returns fn()."""

    def __init__(self) -> None:
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="rig-spawn")
        self._pool.submit(lambda: None).result()  # its thread exists now, at our priority

    def call(self, fn: Callable[[], T]) -> T:
        return self._pool.submit(fn).result()

    def close(self, wait: bool = True) -> None:
        """No more calls; its thread ends after the one in progress (idempotent)."""
        self._pool.shutdown(wait=wait)


def lower_this_thread(nice: int) -> Callable[[], None]:
    """Raise the calling thread's nice by `nice` (Linux only); returns an undo (best effort)."""
    if nice <= 0 or not sys.platform.startswith("linux"):
        return lambda: None
    tid = threading.get_native_id()
    before = os.getpriority(os.PRIO_PROCESS, tid)
    os.setpriority(os.PRIO_PROCESS, tid, min(before + nice, 19))

    def undo() -> None:
        try:
            os.setpriority(os.PRIO_PROCESS, tid, before)
        except PermissionError:  # lowering nice needs privilege: the thread stays polite
            pass

    return undo
