"""The simulated CAN bus, driven by python-can's real socketcand client (no mocks)."""

from __future__ import annotations

import gc
import random
import socket
import subprocess
import sys
import textwrap
import threading
import time
import warnings
from collections.abc import Callable, Iterator

import can
import pytest

from sim.socketcand_server import CAN_ERR_PROT, BusFaults, SocketcandServer

LIVENESS_S = 5.0  # generous: only a hung bus takes this long


pytestmark = pytest.mark.usefixtures("no_leaks")  # every bus, port and thread closes


@pytest.fixture
def server() -> Iterator[SocketcandServer]:
    with SocketcandServer() as srv:
        yield srv


@pytest.fixture
def connect() -> Iterator[Callable[[SocketcandServer], can.BusABC]]:
    buses: list[can.BusABC] = []

    def make(srv: SocketcandServer) -> can.BusABC:
        bus = can.Bus(interface="socketcand", host="127.0.0.1", port=srv.port, channel="can0")
        buses.append(bus)
        return bus

    yield make
    for bus in buses:
        bus.shutdown()


def _msg(can_id: int, data: bytes, ext: bool = False) -> can.Message:
    return can.Message(arbitration_id=can_id, data=data, is_extended_id=ext)


def _recv_n(bus: can.BusABC, n: int) -> list[can.Message]:
    got: list[can.Message] = []
    deadline = time.monotonic() + LIVENESS_S
    while len(got) < n and time.monotonic() < deadline:
        msg = bus.recv(timeout=0.5)
        if msg is not None:
            got.append(msg)
    return got


def _counter(msgs: list[can.Message]) -> list[int]:
    return [int.from_bytes(m.data, "little") for m in msgs]


def _send_counting(bus: can.BusABC, n: int) -> threading.Thread:
    """Send frames 0..n-1 (counter in the data) from a thread, at full speed."""

    def run() -> None:
        for i in range(n):
            bus.send(_msg(0x100, i.to_bytes(4, "little")))

    thread = threading.Thread(target=run)
    thread.start()
    return thread


class Recorder:
    """A device that records frames and answers 0x10 with 0x11."""

    def __init__(self, server: SocketcandServer) -> None:
        self.server = server
        self.seen: list[can.Message] = []

    def on_frame(self, msg: can.Message) -> None:
        self.seen.append(msg)
        if msg.arbitration_id == 0x10:
            self.server.broadcast(_msg(0x11, bytes(msg.data[::-1])), origin=self)


def test_frames_reach_every_other_client_stamped_by_the_server_clock(connect) -> None:
    with SocketcandServer(clock=lambda: 1234.5) as srv:
        a, b, c = connect(srv), connect(srv), connect(srv)
        a.send(_msg(0x7FF, b"\x01\x02\xab"))
        a.send(_msg(0x1ABCDEF0, b"", ext=True))
        assert [m.arbitration_id for m in _recv_n(b, 2)] == [0x7FF, 0x1ABCDEF0]
        b.send(_msg(0x001, bytes(range(8))))  # only now: the order on the bus is then known
        got = _recv_n(c, 3)
        assert [m.arbitration_id for m in got] == [0x7FF, 0x1ABCDEF0, 0x001]
        assert all(m.timestamp == 1234.5 for m in got)
        assert [m.is_extended_id for m in got] == [False, True, False]
        assert [bytes(m.data) for m in got] == [b"\x01\x02\xab", b"", bytes(range(8))]
        assert [m.arbitration_id for m in _recv_n(a, 1)] == [0x001]  # never its own frames
        assert a.recv(timeout=0.1) is None
        assert srv.client_count == 3


def test_5000_frames_at_full_speed_arrive_complete_and_in_order(server, connect) -> None:
    a, b = connect(server), connect(server)
    sender = _send_counting(a, 5000)
    got = _recv_n(b, 5000)
    sender.join()
    assert _counter(got) == list(range(5000))
    assert server.stats.frames_relayed == 5000


def test_an_attached_device_hears_clients_and_its_broadcasts_reach_them(server, connect) -> None:
    device = Recorder(server)
    server.attach(device)
    a, b = connect(server), connect(server)
    a.send(_msg(0x10, b"\x01\x02"))
    assert [(m.arbitration_id, bytes(m.data)) for m in _recv_n(b, 2)] == [
        (0x10, b"\x01\x02"),
        (0x11, b"\x02\x01"),
    ]
    assert [m.arbitration_id for m in _recv_n(a, 1)] == [0x11]
    server.broadcast(_msg(0x20, b"\xff"))  # from this thread, as a device's own timer would
    assert [m.arbitration_id for m in _recv_n(a, 1) + _recv_n(b, 1)] == [0x20, 0x20]
    # it never hears its own answer, and it hears broadcasts without an origin
    assert [m.arbitration_id for m in device.seen] == [0x10, 0x20]
    assert device.seen[0].channel == "can0" and not device.seen[0].is_extended_id


def test_a_failing_device_is_counted_and_the_bus_keeps_running(server, connect) -> None:
    class Broken:
        def on_frame(self, msg: can.Message) -> None:
            raise RuntimeError("simulated device bug")

    server.attach(Broken())
    a, b = connect(server), connect(server)
    a.send(_msg(0x1, b"\x00"))
    a.send(_msg(0x2, b"\x00"))
    assert [m.arbitration_id for m in _recv_n(b, 2)] == [0x1, 0x2]
    assert server.stats.device_errors == 2


def test_drop_and_duplicate_follow_the_seeded_rng_exactly(connect) -> None:
    faults = BusFaults(drop_prob=0.1, duplicate_prob=0.05, seed=42)
    n = 2000
    expected: list[int] = []
    rng = random.Random(faults.seed)  # the documented contract: one draw per frame
    for i in range(n):
        u = rng.random()
        if u >= faults.drop_prob:
            expected += [i] * (2 if u < faults.drop_prob + faults.duplicate_prob else 1)
    dropped = n - len(set(expected))
    with SocketcandServer(faults=faults) as srv:
        a, b = connect(srv), connect(srv)
        sender = _send_counting(a, n)
        got = _recv_n(b, len(expected))
        sender.join()
        assert b.recv(timeout=0.2) is None
        stats = srv.stats
    assert _counter(got) == expected
    assert stats.frames_dropped == dropped and 150 < dropped < 260  # ~Binomial(2000, 0.1)
    assert stats.frames_duplicated == len(expected) - (n - dropped)
    assert stats.frames_in == n and stats.frames_relayed == len(expected)


def test_reordered_frames_all_arrive_with_counted_swaps(connect) -> None:
    with SocketcandServer(faults=BusFaults(reorder_prob=0.1, seed=7)) as srv:
        a, b = connect(srv), connect(srv)
        sender = _send_counting(a, 500)
        got = _counter(_recv_n(b, 500))
        sender.join()
        swaps = sum(x > y for x, y in zip(got, got[1:]))
        assert sorted(got) == list(range(500))
        assert swaps == srv.stats.frames_reordered >= 1


def test_error_burst_after_n_frames_and_on_demand(connect) -> None:
    with SocketcandServer(faults=BusFaults(error_burst_after=3, error_burst_len=4)) as srv:
        a, b = connect(srv), connect(srv)
        for i in range(5):
            a.send(_msg(0x100, bytes([i])))
        got = _recv_n(b, 9)
        kinds = ["E" if m.is_error_frame else m.data[0] for m in got]
        assert kinds == [0, 1, 2, "E", "E", "E", "E", 3, 4]
        assert all(m.arbitration_id == CAN_ERR_PROT for m in got if m.is_error_frame)
        srv.inject_error_burst(2, error_class=0x040)
        # error frames reach every client, the sender of the triggering frame too
        assert [m.arbitration_id for m in _recv_n(a, 6)] == [CAN_ERR_PROT] * 4 + [0x040] * 2
        assert srv.stats.error_frames == 6


def test_bus_off_resets_every_client_after_n_frames(connect) -> None:
    with SocketcandServer(faults=BusFaults(disconnect_after=3)) as srv:
        a, b = connect(srv), connect(srv)
        for i in range(3):
            a.send(_msg(0x100, bytes([i])))
        assert [m.data[0] for m in _recv_n(b, 3)] == [0, 1, 2]
        for bus in (a, b):
            with pytest.raises(can.CanError, match="reset"):
                bus.recv(timeout=LIVENESS_S)
        assert srv.stats.clients_disconnected == 2 and srv.client_count == 0


def test_shutdown_resets_clients_closes_the_port_and_is_idempotent(connect) -> None:
    srv = SocketcandServer()
    a = connect(srv)
    srv.shutdown()
    srv.shutdown()
    with pytest.raises(can.CanError):
        a.recv(timeout=LIVENESS_S)
    with pytest.raises(ConnectionRefusedError):
        socket.create_connection(("127.0.0.1", srv.port), timeout=1).close()
    srv.broadcast(_msg(0x1, b""))  # ignored, not an error: device threads stop in any order


@pytest.mark.parametrize("host", ["0.0.0.0", "192.168.1.10", "::1", "example.com", ""])
def test_a_non_loopback_host_is_refused(host: str) -> None:
    with pytest.raises(ValueError, match="loopback"):
        SocketcandServer(host=host)


def test_a_wrong_bus_name_fails_the_handshake(server) -> None:
    with warnings.catch_warnings():
        # python-can leaves its socket open when the handshake fails; collect it here
        warnings.simplefilter("ignore", ResourceWarning)
        with pytest.raises(can.CanError, match="could not open bus"):
            can.Bus(interface="socketcand", host="127.0.0.1", port=server.port, channel="can9")
        gc.collect()


def test_handshakes_succeed_while_the_bus_is_busy(server, connect) -> None:
    stop = threading.Event()

    def flood() -> None:
        while not stop.is_set():
            for _ in range(10):
                server.broadcast(_msg(0x300, b"\x00" * 8))
            time.sleep(0.001)

    flooder = threading.Thread(target=flood)
    flooder.start()
    try:
        late = [connect(server) for _ in range(10)]  # each raises if a frame joined its "< ok >"
        assert all(_recv_n(bus, 1) for bus in late)
    finally:
        stop.set()
        flooder.join()


_ECHO_CHILD = textwrap.dedent(
    """
    import sys, can
    n = int(sys.argv[2])
    with can.Bus(interface="socketcand", host="127.0.0.1", port=int(sys.argv[1]),
                 channel="can0") as bus:
        print("ready", flush=True)
        for _ in range(n):
            msg = bus.recv(timeout=10)
            if msg is None:
                sys.exit("timed out")
            bus.send(can.Message(arbitration_id=msg.arbitration_id + 1, data=msg.data,
                                 is_extended_id=msg.is_extended_id))
    """
)


def test_a_client_in_another_process_echoes_frames(server, connect) -> None:
    n = 300
    child = subprocess.Popen(
        [sys.executable, "-c", _ECHO_CHILD, str(server.port), str(n)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert child.stdout is not None
        assert child.stdout.readline().strip() == "ready"
        a = connect(server)
        sender = _send_counting(a, n)
        got = _recv_n(a, n)
        sender.join()
        assert [m.arbitration_id for m in got] == [0x101] * n
        assert _counter(got) == list(range(n))
        assert child.wait(timeout=LIVENESS_S) == 0
    finally:
        if child.poll() is None:
            child.kill()
            child.wait()
        if child.stdout is not None:
            child.stdout.close()
