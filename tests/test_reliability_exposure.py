"""Exposure: the simulated rig listens on loopback only; a rig run opens no port.

Sockets are read from /proc: a process's socket inodes (/proc/PID/fd → socket:[N])
matched against the TCP LISTEN rows and the bound UDP rows of /proc/PID/net/{tcp,
tcp6,udp,udp6}. A listening socket on 0.0.0.0, :: or any non-loopback address
would be reachable from the network; none may exist.
"""

from __future__ import annotations

import ipaddress
import os
import socket
from pathlib import Path

import pytest

from rig.config import load_config
from rig.errors import ConfigError
from rig.profile import load_profile
from rig.run.runner import run_profile
from rig.run.sim_process import SimProcess
from sim.rig_sim import SimRig
from sim.socketcand_server import SocketcandServer
from tests.test_run_limits import hardware, profile_file

TCP_LISTEN, UDP_UNCONNECTED = "0A", "07"


def _address(hex_addr: str) -> ipaddress.IPv4Address | ipaddress.IPv6Address:
    """An address of /proc/net/{tcp,udp}[6]: 32-bit words in host (little-endian) order."""
    raw = bytes.fromhex(hex_addr)
    words = b"".join(raw[i:i + 4][::-1] for i in range(0, len(raw), 4))
    return ipaddress.ip_address(words)


def listening(pid: int | str = "self") -> list[tuple[str, str, int]]:
    """(protocol, address, port) of every TCP socket in LISTEN and every bound,
    unconnected UDP socket that process `pid` holds."""
    inodes = set()
    fd_dir = Path(f"/proc/{pid}/fd")
    for fd in os.listdir(fd_dir):
        try:
            target = os.readlink(fd_dir / fd)
        except OSError:
            continue  # closed meanwhile
        if target.startswith("socket:["):
            inodes.add(target[8:-1])
    out = []
    for proto, state in (("tcp", TCP_LISTEN), ("tcp6", TCP_LISTEN),
                         ("udp", UDP_UNCONNECTED), ("udp6", UDP_UNCONNECTED)):
        try:
            lines = Path(f"/proc/{pid}/net/{proto}").read_text().splitlines()[1:]
        except FileNotFoundError:
            continue  # no IPv6 in this kernel
        for line in lines:
            fields = line.split()
            local, st, inode = fields[1], fields[3], fields[9]
            if st == state and inode in inodes:
                addr, port = local.split(":")
                out.append((proto, str(_address(addr)), int(port, 16)))
    return out


def test_the_proc_reader_sees_a_wildcard_listener() -> None:
    """The check itself: a socket on every interface is reported as such."""
    with socket.create_server(("0.0.0.0", 0)) as s:
        port = s.getsockname()[1]
        assert ("tcp", "0.0.0.0", port) in listening()
    with socket.create_server(("127.0.0.1", 0)) as s:
        assert ("tcp", "127.0.0.1", s.getsockname()[1]) in listening()


@pytest.mark.parametrize("host", ["0.0.0.0", "", "::", "192.168.1.10", "::1"])
def test_the_simulated_bus_refuses_a_non_loopback_address(host: str) -> None:
    with pytest.raises(ConfigError, match="loopback"):
        SocketcandServer(host=host)


def test_the_in_process_sim_listens_on_loopback_only() -> None:
    with SimRig(load_config()) as rig:
        assert rig.server.host == "127.0.0.1"
        assert rig.server._listener.getsockname() == ("127.0.0.1", rig.can_port)
        assert ("tcp", "127.0.0.1", rig.can_port) in listening()
        assert all(ipaddress.ip_address(a).is_loopback for _, a, _ in listening())


@pytest.mark.slow
def test_sim_serve_listens_on_loopback_only() -> None:
    """The `sim serve` process (what `rig run` starts with backend "sim")."""
    with SimProcess(load_config()) as sim:
        socks = listening(sim.pid)
        port = int(sim.config.can.extra["port"])
        assert socks == [("tcp", "127.0.0.1", port)]


def test_a_rig_run_opens_no_listening_socket(tmp_path: Path) -> None:
    """Sampled mid-run, after START: the listeners in the process are the sim's own and
    those the test process had before (pytest-rerunfailures keeps one on loopback for
    pytest-xdist's workers), nothing of the rig's."""
    seen: list[list[tuple[str, str, int]]] = []
    spec = profile_file(tmp_path, "small", 1.0, 0.3)

    def progress(text: str) -> None:
        if text.startswith("START"):
            seen.append(listening())

    ambient = listening()
    with SimRig(load_config()) as rig:
        before = listening()
        result = run_profile(hardware(rig), load_profile(spec), spec.read_text(), tmp_path,
                             progress=progress)
        after = listening()
    assert result.status == "success", result.reason
    assert ("tcp", "127.0.0.1", rig.can_port) not in ambient
    assert sorted(before) == sorted(after) == sorted(seen[0]) == sorted(
        ambient + [("tcp", "127.0.0.1", rig.can_port)])
