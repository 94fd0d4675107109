"""Start the simulated rig (`sim serve`) as a child process, by command line only.

`rig` never imports `sim` (import-linter); with `backend = "sim"` it runs
`python -m sim serve --state-file …` and reads the endpoints from that JSON
file, then points its configuration at them. Stopping sends SIGTERM and waits.
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path
from types import MappingProxyType
from typing import Self

from rig.config import RigConfig
from rig.errors import RigError

START_TIMEOUT_S = 150.0  # a cold numba cache compiles the integrator first (~40 s idle)


class SimProcess:
    """A running `sim serve`; `config` is the given configuration pointed at it."""

    def __init__(self, config: RigConfig, seed: int = 0, extra_args: tuple[str, ...] = ()):
        self._dir = tempfile.TemporaryDirectory(prefix="rig-sim-")
        state = Path(self._dir.name) / "state.json"
        cmd = [sys.executable, "-m", "sim", "serve", "--seed", str(seed),
               "--state-file", str(state), *extra_args]
        if config.source != "<memory>":
            cmd += ["--config", config.source]
        # stderr to a file, not a pipe: a pipe nobody drains would block the sim when full
        self._log_path = Path(self._dir.name) / "stderr.log"
        with open(self._log_path, "wb") as log:
            self._proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=log)
        try:
            endpoints = self._wait_for(state)
        except BaseException:
            self.stop()
            raise
        can = endpoints["can"]
        extra = dict(config.can.extra, host=can["host"], port=int(can["port"]))
        self.config = replace(
            config, can=replace(config.can, interface=can["interface"], channel=can["channel"],
                                extra=MappingProxyType(extra)),
            serial=replace(config.serial, path=endpoints["serial"]["path"]))

    @property
    def pid(self) -> int:
        return self._proc.pid

    def _wait_for(self, state: Path) -> dict:
        deadline = time.monotonic() + START_TIMEOUT_S
        while time.monotonic() < deadline:
            if state.exists():
                return json.loads(state.read_text(encoding="utf-8"))
            if self._proc.poll() is not None:
                err = self._log_path.read_text(errors="replace").strip().splitlines()
                raise RigError(f"sim serve exited with code {self._proc.returncode} before it "
                               f"was ready: {err[-1] if err else 'no message'}")
            time.sleep(0.02)
        raise RigError(f"sim serve not ready after {START_TIMEOUT_S:.0f} s (limit)")

    def stop(self) -> None:
        """SIGTERM, wait (kill after 10 s); idempotent."""
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        self._dir.cleanup()

    def __enter__(self) -> Self:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
