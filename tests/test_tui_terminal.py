"""The real `rig tui` in a real terminal: tmux at 80 x 24, keys sent, the screen read back.

Start, arm and run profile A on the simulated rig (`sim serve`, started by the
TUI itself as with `backend = "sim"`), see the summary, quit; the run file must
say success. tmux is required: without it this test fails (CI installs it).
"""

from __future__ import annotations

import shlex
import shutil
import subprocess
import sys
import time
import uuid
from pathlib import Path

import pytest

from rig.runfile import open_run

COLD_START_S = 90.0  # a cold numba cache compiles the simulator first (~15 s, slower loaded)


class Tmux:
    """One tmux server of our own (-L), one 80 x 24 session running `command`."""

    def __init__(self, command: str) -> None:
        self.socket = f"rig-tui-test-{uuid.uuid4().hex[:8]}"
        self("new-session", "-d", "-s", "tui", "-x", "80", "-y", "24", command)

    def __call__(self, *args: str) -> str:
        done = subprocess.run(["tmux", "-L", self.socket, *args], check=False, capture_output=True,
                              text=True, timeout=30)
        assert done.returncode == 0, f"tmux {args[0]}: {done.stderr.strip()}"
        return done.stdout

    def screen(self) -> str:
        return self("capture-pane", "-p", "-t", "tui")

    def keys(self, *keys: str) -> None:
        self("send-keys", "-t", "tui", *keys)

    def wait_for(self, text: str, timeout: float, failed: tuple[str, ...] = ()) -> str:
        end = time.monotonic() + timeout
        while True:
            screen = self.screen()
            if text in screen:
                return screen
            if any(f in screen for f in failed):
                pytest.fail(f"waiting for {text!r}:\n{screen}")
            if time.monotonic() > end:
                pytest.fail(f"{text!r} not on the screen after {timeout:.0f} s:\n{screen}")
            time.sleep(0.5)

    def kill(self) -> None:
        subprocess.run(["tmux", "-L", self.socket, "kill-server"], check=False, capture_output=True,
                       timeout=30)


@pytest.mark.slow
def test_run_profile_a_in_tmux_see_the_summary_and_quit(tmp_path: Path) -> None:
    assert shutil.which("tmux"), "tmux is needed for this test; .ci/run installs it"
    out = tmp_path / "runs"
    command = (f"cd {shlex.quote(str(Path(__file__).parent.parent))} && "
               f"{shlex.quote(sys.executable)} -m rig.cli tui --out {shlex.quote(str(out))}; "
               "echo EXITED $?; sleep 60")
    tmux = Tmux(command)
    try:
        # the footer can be painted before the setup pane's body (seen once on a loaded
        # machine): wait for the body's own text
        setup = tmux.wait_for("least margin", 30)
        assert "Configuration" in setup and "a Arm" in setup and "1 X1" in setup
        tmux.keys("a")
        tmux.wait_for("ARM THE TABLE?", 10)
        tmux.keys("y")
        summary = tmux.wait_for("success in", COLD_START_S, failed=("ABORT", "FAILED"))
        assert "SUCCESS" in summary and "table_u" in summary
        tmux.keys("q")
        tmux.wait_for("EXITED 0", 30)
    finally:
        tmux.kill()
    (path,) = out.glob("*_A.h5")
    assert open_run(path).status.exit_status == "success"
