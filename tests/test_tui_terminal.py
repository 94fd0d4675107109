"""The real `rig tui` in a real terminal: tmux at 80 x 24, keys sent, the screen read back.

Start, arm and run profile A on the simulated rig (`sim serve`, started by the
TUI itself as with `backend = "sim"`), see the summary; then a long profile typed
into Setup's path box, armed, and e-stopped with space from inside that box (the
keys of issue 18); quit. The run files must say success, then abort. tmux is
required: without it this test fails (CI installs it).
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
from tests.test_run_limits import profile_file

COLD_START_S = 150.0  # a cold numba cache compiles the simulator first (~40 s, slower loaded)


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
def test_run_profile_a_in_tmux_see_the_summary_estop_from_the_path_box_and_quit(
        tmp_path: Path) -> None:
    assert shutil.which("tmux"), "tmux is needed for this test; .ci/run installs it"
    out = tmp_path / "runs"
    command = (f"cd {shlex.quote(str(Path(__file__).parent.parent))} && "
               f"{shlex.quote(sys.executable)} -m rig.cli tui --out {shlex.quote(str(out))}; "
               "echo EXITED $?; sleep 60")
    tmux = Tmux(command)
    try:
        # the footer can be painted before the setup pane's body (seen once on a loaded
        # machine): wait for the body's own text
        tmux.wait_for("least margin", 30)
        # and each of the rest on its own: one capture caught the footer painted while
        # the configuration table was not yet (CI, under load)
        for text in ("Configuration", "a Arm", "1 X1"):
            tmux.wait_for(text, 10)
        tmux.keys("a")
        tmux.wait_for("ARM THE TABLE?", 10)
        tmux.keys("y")
        summary = tmux.wait_for("success in", COLD_START_S, failed=("ABORT", "FAILED"))
        assert "SUCCESS" in summary and "table_u" in summary
        long = profile_file(tmp_path, "long", 1.0, 8.0)
        tmux.keys("1", "Down", "Down", "Down", "Enter")  # file…, into its box
        box = "esc Leave box (space: E-STOP in a run)"  # the footer while in a text box
        tmux.wait_for(box, 10)  # (keys sent before the focus moves still go to the list)
        tmux.keys("-l", str(long))
        tmux.keys("Enter", "Escape")  # load it; Esc: back to the profile list
        tmux.wait_for("a Arm space E-STOP", 10)
        assert "profile long" in tmux.screen()
        tmux.keys("a")
        tmux.wait_for("ARM THE TABLE?", 10)
        tmux.keys("y")
        tmux.wait_for("long  running", 30, failed=("ABORT", "FAILED"))
        tmux.keys("1", "Enter")  # Setup, into the path box…
        tmux.wait_for(box, 5)
        tmux.keys("Space")  # …and the e-stop from there
        stopped = tmux.wait_for("abort in", 15)
        assert "ABORT" in stopped
        tmux.keys("q")
        tmux.wait_for("EXITED 0", 30)
    finally:
        tmux.kill()
    (path,) = out.glob("*_A.h5")
    assert open_run(path).status.exit_status == "success"
    (path,) = out.glob("*_long.h5")
    status = open_run(path).status
    assert status.exit_status == "abort" and "emergency stop" in status.reason
