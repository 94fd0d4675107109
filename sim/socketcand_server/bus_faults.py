"""What a frame reaching the simulated bus may suffer, the counters, and the relay applying both.

The relay runs on the server's thread only. Two things reach it from other
threads, each as one attribute write: new faults (`faults`, a reference swap)
and a stall (`stalled_until`).
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field

from sim.socketcand_server.protocol import CAN_ERR_PROT, Frame

REORDER_HOLD_S = 0.005  # a held-back frame goes out alone if nothing follows it this soon


@dataclass(frozen=True)
class BusFaults:
    """Faults applied to every frame reaching the bus, clients' and devices' alike.

    One uniform draw u per frame, in arrival order, from Random(seed):
    u < drop_prob drops it; then the next duplicate_prob duplicates it; then the
    next reorder_prob holds it back until after the following frame.
    error_burst_after / disconnect_after: frames after these faults take effect
    before a burst of error_burst_len error frames (class error_class) /
    before every client is disconnected (bus-off). None: never.
    """

    drop_prob: float = 0.0
    duplicate_prob: float = 0.0
    reorder_prob: float = 0.0
    seed: int = 0
    error_burst_after: int | None = None
    error_burst_len: int = 10
    error_class: int = CAN_ERR_PROT
    disconnect_after: int | None = None


@dataclass
class RelayStats:
    """Counters since start. frames_in: frames offered by clients and devices.
    frames_relayed: frames put on the bus (a duplicate counts twice).
    clients_disconnected: by bus-off or because their output buffer overflowed."""

    frames_in: int = 0
    frames_relayed: int = 0
    frames_dropped: int = 0  # by drop_prob or while the bus was stalled
    frames_duplicated: int = 0
    frames_reordered: int = 0
    error_frames: int = 0
    clients_disconnected: int = 0
    bad_commands: int = 0
    device_errors: int = 0


@dataclass
class _FaultState:
    faults: BusFaults
    rng: random.Random = field(init=False)
    frames_seen: int = 0

    def __post_init__(self) -> None:
        self.rng = random.Random(self.faults.seed)


class FaultyRelay:
    """Applies `BusFaults` to each frame offered to the bus and delivers what is left.

    deliver: puts one frame on the bus. error_burst(count, error_class) and
    disconnect_all(): what the faults' triggers fire. stats: counted in place.
    """

    def __init__(
        self,
        faults: BusFaults,
        stats: RelayStats,
        deliver: Callable[[Frame], None],
        error_burst: Callable[[int, int], None],
        disconnect_all: Callable[[], None],
    ) -> None:
        self._fault_state = _FaultState(faults)
        self._stats = stats
        self._deliver = deliver
        self._error_burst = error_burst
        self._disconnect_all = disconnect_all
        self.held: Frame | None = None
        self.held_until = 0.0  # monotonic s
        self.stalled_until = 0.0  # monotonic s: no frame reaches the bus before then

    @property
    def faults(self) -> BusFaults:
        """The faults in effect; assigning new ones reseeds the RNG and restarts the triggers."""
        return self._fault_state.faults

    @faults.setter
    def faults(self, faults: BusFaults) -> None:
        self._fault_state = _FaultState(faults)  # one reference swap: no lock needed

    def offer(self, frame: Frame) -> None:
        """A frame reaches the bus: count it, apply the faults, deliver what is left."""
        fs = self._fault_state
        f = fs.faults
        self._stats.frames_in += 1
        fs.frames_seen += 1
        u = fs.rng.random()
        if u < f.drop_prob or self.stalled_until > time.monotonic():
            self._stats.frames_dropped += 1
        elif u < f.drop_prob + f.duplicate_prob:
            self._stats.frames_duplicated += 1
            self._deliver(frame)
            self._deliver(frame)
        elif u < f.drop_prob + f.duplicate_prob + f.reorder_prob and self.held is None:
            self.held = frame
            self.held_until = time.monotonic() + REORDER_HOLD_S
        else:
            self._deliver(frame)
            if self.held is not None:
                self._stats.frames_reordered += 1
                self.release_held()
        self._fire_triggers(fs)

    def _fire_triggers(self, fs: _FaultState) -> None:
        f = fs.faults
        if fs.frames_seen == f.error_burst_after:
            self._error_burst(f.error_burst_len, f.error_class)
        if fs.frames_seen == f.disconnect_after:
            self._disconnect_all()

    def release_held(self) -> None:
        """Deliver the held-back frame, if any."""
        frame, self.held = self.held, None
        if frame is not None:
            self._deliver(frame)
