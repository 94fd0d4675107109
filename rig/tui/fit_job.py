"""`analysis fit` for the Results screen: a subprocess, its progress lines, its JSON.

`rig` never imports `analysis` (import-linter), so the fit runs as
`python -m analysis.cli fit FILES --mass-lb 6000 --json OUT --report DIR`; its
stderr progress ("analysis fit [  1.2 s] …") is streamed line by line, its
stdout (the text report) goes to DIR/fit.txt, and the JSON is read at the end
(`rig.tui.fit_summary`, which checks its schema version).
"""

from __future__ import annotations

import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

# summarize: the reader's entry point, importable where the job is
from rig.tui.fit_summary import FitSummary, read_summary, summarize  # noqa: F401

MASS_LB = 6000.0  # the report's isolated mass

#: (files, json path, report dir) -> argv; tests swap in a stand-in fit
FitArgvBuilder = Callable[[Sequence[Path], Path, Path], list[str]]


def analysis_command(files: Sequence[Path], json_path: Path, report: Path) -> list[str]:
    return [sys.executable, "-m", "analysis.cli", "fit", *map(str, files),
            "--mass-lb", f"{MASS_LB:g}", "--json", str(json_path), "--report", str(report)]


@dataclass
class FitJob:
    """One fit of `files` into `report`; `execute()` on a worker thread, `cancel()` from any."""

    files: tuple[Path, ...]
    report: Path
    command: FitArgvBuilder = analysis_command
    lines: deque[str] = field(default_factory=lambda: deque(maxlen=200))
    summary: FitSummary | None = None
    error: str = ""
    returncode: int | None = None
    started: float = field(default_factory=time.monotonic)
    finished: float | None = None
    _proc: subprocess.Popen | None = None
    _cancelled: threading.Event = field(default_factory=threading.Event)

    @property
    def json_path(self) -> Path:
        return self.report / "fit.json"

    @property
    def text_path(self) -> Path:
        return self.report / "fit.txt"

    @property
    def html_path(self) -> Path:
        return self.report / "index.html"

    @property
    def running(self) -> bool:
        return self.finished is None

    def execute(self) -> FitSummary | None:
        try:
            self._run()
        except Exception as exc:  # noqa: BLE001 - shown on the Results screen
            self.error = f"{type(exc).__name__}: {exc}".splitlines()[0]
        finally:
            self.finished = time.monotonic()
        return self.summary

    def _run(self) -> None:
        self.report.mkdir(parents=True, exist_ok=True)
        argv = self.command(self.files, self.json_path, self.report)
        with open(self.text_path, "w", encoding="utf-8") as out:
            self._proc = subprocess.Popen(argv, stdout=out, stderr=subprocess.PIPE, text=True,
                                          bufsize=1, stdin=subprocess.DEVNULL)
            if self._cancelled.is_set():
                self._proc.terminate()
            assert self._proc.stderr is not None
            with self._proc.stderr:
                for line in self._proc.stderr:
                    self.lines.append(line.rstrip())
            self.returncode = self._proc.wait()
        if self._cancelled.is_set():
            self.error = "cancelled by the operator"
        elif self.returncode != 0:
            last = next((ln for ln in reversed(self.lines) if ln.strip()), "no message")
            self.error = f"analysis fit exited with code {self.returncode}: {last}"
        else:
            self.summary = read_summary(self.json_path)

    def cancel(self) -> None:
        """Stop the fit (SIGTERM); idempotent, any thread."""
        self._cancelled.set()
        proc = self._proc
        if proc is not None and proc.poll() is None:
            proc.terminate()
