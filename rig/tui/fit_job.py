"""`analysis fit` for the Results screen: a subprocess, its progress lines, its JSON.

`rig` never imports `analysis` (import-linter), so the fit runs as
`python -m analysis.cli fit FILES --mass-lb 6000 --json OUT --report DIR`; its
stderr progress ("analysis fit [  1.2 s] …") is streamed line by line, its
stdout (the text report) goes to DIR/fit.txt, and the JSON is read at the end.
"""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from rig.units import from_si, us_unit

MASS_LB = 6000.0  # the report's isolated mass

#: (files, json path, report dir) -> argv; tests swap in a stand-in fit
FitArgvBuilder = Callable[[Sequence[Path], Path, Path], list[str]]


def analysis_command(files: Sequence[Path], json_path: Path, report: Path) -> list[str]:
    return [sys.executable, "-m", "analysis.cli", "fit", *map(str, files),
            "--mass-lb", f"{MASS_LB:g}", "--json", str(json_path), "--report", str(report)]


@dataclass(frozen=True)
class Constant:
    """One identified constant, SI (`unit`); half95 (the 95 % interval's half width, as
    `analysis fit` prints it) None where it was held or not estimated."""

    name: str
    value: float
    half95: float | None
    unit: str
    held: bool = False

    def shown(self, units: str) -> tuple[str, str, str]:
        """(value, ± 95 %, unit) as text in "si" or "us"."""
        unit = self.unit if units == "si" else us_unit(self.unit)
        value = float(from_si(self.value, unit))
        ci = "" if self.half95 is None else f"± {float(from_si(self.half95, unit)):.3g}"
        return f"{value:.5g}", ("held" if self.held and not ci else ci), unit


@dataclass(frozen=True)
class LoopStep:
    """A step of closing the loop: the effect added, its evidence, error per run before/after."""

    added: str
    statistic: float
    explanation: str
    before: dict[str, float]  # run -> residual / sensor noise
    after: dict[str, float]


@dataclass(frozen=True)
class FitSummary:
    """What the Results screen shows of a fit's JSON."""

    constants: tuple[Constant, ...]
    runs: tuple[str, ...]
    steps: tuple[LoopStep, ...]
    before: dict[str, float]  # run -> residual / noise, base model
    after: dict[str, float]  # after the loop (= before without one)
    effects_added: tuple[str, ...]
    unexplained: str  # "" if the residual is explained


def summarize(doc: dict) -> FitSummary:
    """The Results screen's view of `analysis fit --json` output."""
    constants = tuple(Constant(n, float(e["value"]), _half(e.get("ci95")), str(e["unit"]),
                               bool(e.get("held", False)))
                      for n, e in doc["parameters"].items())
    base = {r: float(e["residual_over_noise"]) for r, e in doc.get("error", {}).items()}
    before = _rno(doc.get("error_before")) or base
    after = _rno(doc.get("error_after")) or before
    steps = tuple(LoopStep(s["added"], float(s["evidence"].get("value", float("nan"))),
                           str(s["evidence"].get("explanation", "")),
                           _rno(s["error_before"]), _rno(s["error_after"]))
                  for s in doc.get("loop", []))
    unexplained = doc.get("unexplained") or {}
    text = unexplained.get("description", "") if unexplained.get("value") else ""
    return FitSummary(constants, tuple(doc.get("runs", {})), steps, before, after,
                      tuple(doc.get("effects_added", [])), text)


def _rno(errors: dict | None) -> dict[str, float]:
    return {r: float(e["residual_over_noise"]) for r, e in (errors or {}).items()}


def _half(ci: object) -> float | None:
    """The half width of a [low, high] interval from the JSON, or None."""
    if not isinstance(ci, list | tuple) or len(ci) != 2:
        return None
    low, high = _num(ci[0]), _num(ci[1])
    return None if low is None or high is None else (high - low) / 2.0


def _num(value: object) -> float | None:
    return None if value is None else float(value)  # type: ignore[arg-type]


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
            self.summary = summarize(json.loads(self.json_path.read_text(encoding="utf-8")))

    def cancel(self) -> None:
        """Stop the fit (SIGTERM); idempotent, any thread."""
        self._cancelled.set()
        proc = self._proc
        if proc is not None and proc.poll() is None:
            proc.terminate()
