"""Start a `python -m MODULE` child in its own session, linked by a socket pair.

The run and the simulated rig each run in a child of their own (see
run_process and sim_host for why); both are started the same way: the child
gets its end of the pair as an inherited descriptor, stderr goes to a
temporary file the caller reads after, and a new session keeps it out of the
display's CPU share.
"""

from __future__ import annotations

import socket
import subprocess
import sys
from multiprocessing.connection import Connection
from typing import IO


def spawn_child(module: str, stderr: IO[bytes]) -> tuple[subprocess.Popen, Connection]:
    """`python -m module FD` with FD its end of a socket pair; returns it and our end."""
    ours, theirs = socket.socketpair()
    try:
        proc = subprocess.Popen(
            [sys.executable, "-m", module, str(theirs.fileno())],
            pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL, stderr=stderr, start_new_session=True)
    except BaseException:
        ours.close()
        raise
    finally:
        theirs.close()  # ours only: EOF reaches us when the child ends
    return proc, Connection(ours.detach())
