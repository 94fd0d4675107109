"""How the Run screen shows a LiveStatus: the state line, the actuators, the bus's health.

Pure functions from data to Rich renderables, so they are tested without a terminal.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np
from rich.text import Text

from rig.config import RigConfig
from rig.run.status import LiveStatus
from rig.tui.widgets import length, length_unit
from rig.wire import can_messages as cm
from rig.wire.bus_load import bus_load

STATUS_STYLE = {"RUNNING": "green", "ENABLED": "cyan", "SAFE_STATE": "yellow",
                "FAULT": "bold red", "?": "dim"}


@dataclass
class BusMeter:
    """CAN bus load over the last second: received CAN frames/s plus the setpoints we send.

    load = (received CAN/s + setpoints sent/s) × mean worst-case bits per frame / bitrate.
    """

    config: RigConfig
    window_s: float = 1.0
    _seen: deque[tuple[float, int]] = field(default_factory=deque)
    load: float = float("nan")  # fraction of the bitrate

    def update(self, status: LiveStatus) -> float:
        seen = self._seen
        if seen and status.elapsed <= seen[-1][0]:
            return self.load
        seen.append((status.elapsed, status.frames.get("can", 0)))
        while len(seen) > 2 and seen[-1][0] - seen[1][0] >= self.window_s:
            seen.popleft()
        if len(seen) >= 2:
            (t0, n0), (t1, n1) = seen[0], seen[-1]
            rx = (n1 - n0) / (t1 - t0)
            tx = len(cm.ACTUATORS) * self.config.rates.setpoint if status.phase == "running" else 0
            budget = bus_load(self.config)
            bits = budget.bits_per_s("worst") / budget.frames_per_s
            self.load = (rx + tx) * bits / self.config.can.bitrate
        return self.load


def state_line(label: str, status: LiveStatus | None, stopped: bool) -> Text:
    """`A  running  t 1.23 / 3.00 s  remaining 1.77 s`, with the e-stop shown when pressed."""
    if status is None:
        text = Text(f"{label}  starting…", style="bold")
    else:
        remaining = max(status.duration - max(status.elapsed, 0.0), 0.0)
        phase = status.status.upper() if status.phase == "ended" else status.phase
        style = {"SUCCESS": "bold green", "ABORT": "bold red", "FAIL": "bold red"}.get(phase,
                                                                                      "bold")
        text = Text.assemble((f"{label}  ", "bold"), (f"{phase:<9}", style),
                             f" t {status.elapsed:6.2f} / {status.duration:.2f} s"
                             f"  remaining {remaining:5.2f} s")
    if stopped:
        text.append("  E-STOP", style="bold white on red")
    return text


def actuator_table(status: LiveStatus | None, units: str) -> Text:
    """Setpoint, feedback, following error (extension, in or m) and status of the six.

    Plain fixed-width text, not a Rich Table: it is redrawn 10+ times a second.
    """
    unit = length_unit(units)
    heard = " (last heard)" if status is not None and status.phase == "ended" else ""
    text = Text(f"{'act':<4}{'setpt ' + unit:>10}{'feedbk ' + unit:>11}{'error ' + unit:>10}"
                f"  status{heard}\n", style="bold")
    for a in status.actuators if status is not None else ():
        text.append(f"{a.index:<4}{length(a.setpoint, units):>10}{length(a.feedback, units):>11}"
                    f"{length(a.following_error, units):>10}  ")
        text.append(a.status + (f" f{a.faults}" if a.faults else ""),
                    style=STATUS_STYLE.get(a.status, ""))
        text.append("\n")
    text.rstrip()
    return text


def health_table(status: LiveStatus | None, load: float) -> Text:
    """frames/s, lost frames, CRC errors, bus load, samples: 6 lines of 26 columns."""
    if status is None:
        return Text("")
    f, lost = status.frames, status.lost
    lost_n = lost.get("can", 0) + lost.get("serial", 0)
    rows: list[tuple[str, str, str]] = [
        ("frames/s", f"{status.frames_per_s:,.0f}", ""),
        ("CAN/serial", f"{f.get('can', 0)}/{f.get('serial', 0)}", ""),
        ("lost CAN+ser", f"{lost.get('can', 0)}+{lost.get('serial', 0)}",
         "bold red" if lost_n else "green"),
        ("CRC errors", str(status.crc_errors), "bold red" if status.crc_errors else "green"),
        ("CAN bus load", "—" if not np.isfinite(load) else f"{load:.0%}", ""),
        ("samples u/x", f"{f.get('table', 0)}/{f.get('mass', 0)}", ""),
    ]
    text = Text()
    for i, (label, value, style) in enumerate(rows):
        text.append(f"{label:<13}", style="bold")
        text.append(f"{value:>13}", style=style)
        if i < len(rows) - 1:
            text.append("\n")
    return text
