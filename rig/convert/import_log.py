"""`rig import`: a CAN log written by another tool made into a run file, the live rig's way.

The bench's own tools log the bus too: Vector (BLF, ASC), PEAK (TRC), python-can
(CSV, canutils .log) and ASAM MDF 4 bus logging (.mf4). python-can's `LogReader`
reads each, and every frame goes through `rig.run.recorder.Recorder`, as a frame
received in `rig run` does: kept raw in /raw/can, decoded by rig.wire.can_messages,
counted for loss, the sensors' device clocks fitted onto the log's time stamps and
the samples placed on that fit, holes marked in /gaps. So a run file from
`rig import` reads like one from `rig run`; /meta backend is "import" and every
channel's `source` begins `import:LOG`. The ActuatorSetpoint frames are placed as
`rig run` places the setpoints it sends: at START + (index − start sample) / rate.

The DBC given is checked to describe the rig's messages exactly as
data/isolator_rig.dbc does (rig.wire.can_messages.bench_database). The rig's own mass
sensor is on the serial port, which no CAN log holds: only a bench whose DBC adds a
`MassSensor` message (a mass sensor on CAN) gives mass_x. An import that cannot
make both table_u and mass_x is refused, naming the channels it found, and leaves
no file. Time: t = 0 is the log's first frame; /meta start_time is that frame's
wall-clock time when the log's stamps are absolute (ASC is read as absolute).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

import can
from cantools.database.can import Database

from rig.config import RigConfig
from rig.convert.failed_open import release
from rig.errors import DataError
from rig.paths import data_file
from rig.run.recorder import Recorder
from rig.runfile import RunInfo, RunWriter, standard_channels
from rig.wire import can_messages as cm
from rig.wire.can_messages import CommandKind, RigCommand, Setpoint

#: what python-can's LogReader reads (each also gzip-compressed: .blf.gz, ...)
FORMATS = {".blf": "Vector BLF", ".asc": "Vector ASC", ".trc": "PEAK TRC",
           ".csv": "python-can CSV", ".log": "canutils", ".mf4": "ASAM MDF 4 bus logging"}
ABSOLUTE_AFTER = 1e8  # s: stamps past 1973 are Unix times; smaller ones count from the log's start
BLOCK_ROWS = 1000  # rows per block write: an import is not read live


@dataclass
class ImportResult:
    """What `import_log` wrote: the file, the frames read, samples per channel, notes."""

    path: Path
    log: Path
    frames: int
    duration: float  # s, first to last frame
    samples: dict[str, int]
    notes: list[str] = field(default_factory=list)

    def summary(self) -> str:
        """A few lines for the terminal."""
        lines = [(f"{self.path}: {self.frames:,} CAN frames over {self.duration:.3f} s "
                  f"imported from {self.log}")]
        lines += [f"  {name} {n:,} samples" for name, n in self.samples.items()
                  if n and not name.startswith("actuator_")]
        for kind in ("setpoint", "feedback", "status"):
            n = {i: self.samples.get(f"actuator_{kind}_{i}", 0) for i in cm.ACTUATORS}
            if len(set(n.values())) == 1:
                counts = f"{n[1]:,} samples each"
            else:
                counts = ", ".join(f"{i}: {k:,}" for i, k in n.items()) + " samples"
            lines.append(f"  actuator_{kind}_1..6 {counts}")
        lines += [f"  note: {n}" for n in self.notes]
        return "\n".join(lines)


def import_log(log: str | os.PathLike[str], out: str | os.PathLike[str], config: RigConfig,
               dbc: str | os.PathLike[str] | None = None) -> ImportResult:
    """Decode CAN log `log` with `dbc` (default the rig's) into the new run file `out`.

    `config` gives the sensors' scale and offset, the setpoint rate and the payload
    mass (its file is stored in /meta). DataError names the file and the reason: an
    unknown format, a corrupt log, no frame of the DBC, no table_u or no mass_x.
    """
    log, out = Path(log), Path(out)
    kind = _format(log)
    dbc_path = Path(dbc) if dbc is not None else data_file("isolator_rig.dbc")
    db = cm.bench_database(dbc_path)
    with _open(log, kind) as reader:
        frames = iter(reader)
        first = _next(frames, log, kind)
        if first is None:
            raise DataError(f"{log}: no CAN frames in this {kind} file")
        return _write(log, out, config, db, first, frames, kind)


def _write(log: Path, out: Path, config: RigConfig, db: Database, first: can.Message,
           frames, kind: str) -> ImportResult:
    start_unix = first.timestamp
    absolute = start_unix > ABSOLUTE_AFTER
    start = datetime.fromtimestamp(start_unix, UTC) if absolute else None
    info = RunInfo("", "", "import", configuration_toml=_config_text(config, log, kind))
    channels = standard_channels(_sources(log, db))
    seen = _Seen()
    writer = RunWriter(out, info, channels=channels, block_rows=BLOCK_ROWS, start=start)
    try:  # refuses an existing file above; from here a failed import leaves no file
        with writer:
            rec = Recorder(writer, config, start_unix, 0.0, db)
            setpoints = _Setpoints(writer, config.rates.setpoint)
            msg: can.Message | None = first
            while msg is not None:
                seen.frame(msg)
                if len(msg.data) <= 8:  # an FD frame of more cannot go in /raw/can
                    m = rec.can_frame(msg)
                    seen.decoded += m is not None
                    if isinstance(m, Setpoint):
                        setpoints.setpoint(m)
                    elif isinstance(m, RigCommand):
                        setpoints.command(msg.timestamp - start_unix, m)
                msg = _next(frames, log, kind)
            rec.finish()
            writer.flush()
            samples = {k.removeprefix("channels/"): n for k, n in writer.rows_written.items()
                       if k.startswith("channels/")}
            _refuse_unless_usable(log, db, seen, samples)
    except BaseException:
        out.unlink(missing_ok=True)
        raise
    notes = seen.notes(db) + setpoints.notes() + _faults(rec.faults)
    if not absolute:
        notes.append("the log's time stamps count from its start: /meta start_time is the "
                     "time of the import")
    return ImportResult(out, log, seen.frames, seen.last - start_unix, samples, notes)


def _faults(faults: list[str]) -> list[str]:
    """What the live watchdogs would have stopped a run for, as notes (an import aborts
    nothing): the first three and how many more."""
    more = [f"and {len(faults) - 3} more faults as logged"] if len(faults) > 3 else []
    return [f"as logged: {f}" for f in faults[:3]] + more


def _format(log: Path) -> str:
    if not log.exists():
        raise DataError(f"{log}: no such file")
    suffixes = [s.lower() for s in log.suffixes]
    suffix = suffixes[-2] if suffixes[-1:] == [".gz"] and len(suffixes) > 1 else log.suffix
    kind = FORMATS.get(suffix.lower())
    if kind is None:
        raise DataError(f"{log}: not a CAN log rig import reads (suffixes: "
                        f"{', '.join(FORMATS)}, each also .gz)")
    return kind


def _open(log: Path, kind: str) -> can.io.generic.MessageReader:
    # ASC stamps count from its start unless asked: read them as the Unix times they are
    extra = {"relative_timestamp": False} if kind == FORMATS[".asc"] else {}
    try:
        return can.LogReader(log, **extra)
    except Exception as e:  # noqa: BLE001 - each reader raises its own types for a bad header
        release(e)  # a half-built reader's open file (MF4Reader: asammdf's too)
        raise DataError(f"{log}: not a readable {kind} file: {type(e).__name__}: {e}") from None


def _next(frames, log: Path, kind: str) -> can.Message | None:
    """The log's next frame, None at its end; DataError for a corrupt log."""
    try:
        return next(frames)
    except StopIteration:
        return None
    except Exception as e:  # noqa: BLE001 - struct, zlib, ValueError, each reader's own
        raise DataError(f"{log}: not a readable {kind} file: {type(e).__name__}: {e}") from None


class _Seen:
    """What the log held, for the summary and the refusals."""

    def __init__(self) -> None:
        self.frames = self.decoded = self.too_long = 0
        self.ids: set[int] = set()
        self.channels: set[str] = set()
        self.last = 0.0

    def frame(self, msg: can.Message) -> None:
        self.frames += 1
        self.ids.add(msg.arbitration_id)
        self.channels.add(str(msg.channel))
        self.last = max(self.last, msg.timestamp)
        self.too_long += len(msg.data) > 8

    def notes(self, db: Database) -> list[str]:
        out = []
        other = sorted(self.ids - cm.known_ids(db))
        if other:
            shown = ", ".join(f"0x{i:03X}" for i in other[:8]) + (" …" if len(other) > 8 else "")
            out.append(f"frames of {len(other)} ids not the rig's kept raw, not decoded: {shown}")
        if self.too_long:
            out.append(f"{self.too_long} CAN FD frames of more than 8 bytes left out")
        if len(self.channels) > 1:
            out.append(f"frames from {len(self.channels)} bus channels "
                       f"({', '.join(sorted(self.channels))}) taken as one bus")
        return out


class _Setpoints:
    """ActuatorSetpoint frames placed as `rig run` places the ones it sends (module doc)."""

    def __init__(self, writer: RunWriter, rate: float) -> None:
        self.w, self.rate = writer, rate
        self.start: tuple[float, int] | None = None  # (t of START, its start sample)
        self.index: dict[int, int] = {}  # actuator → last full sample index
        self.held: list[tuple[int, int, float]] = []  # before START: when is not known yet

    def command(self, t: float, m: RigCommand) -> None:
        if m.command == CommandKind.START and self.start is None:
            self.start = (t, m.start_sample)
            for item in self.held:
                self._write(*item)
            self.held = []

    def setpoint(self, m: Setpoint) -> None:
        last = self.index.get(m.actuator)
        k = m.sequence if last is None else cm.unwrap(last, m.sequence,
                                                      cm.SETPOINT_SEQUENCE_BITS)
        if k == last:
            return  # a repeat
        self.index[m.actuator] = k
        if self.start is None:
            self.held.append((m.actuator, k, m.position))
        else:
            self._write(m.actuator, k, m.position)

    def _write(self, actuator: int, k: int, position: float) -> None:
        t0, s0 = self.start
        self.w.sample(f"actuator_setpoint_{actuator}", t0 + (k - s0) / self.rate, position)

    def notes(self) -> list[str]:
        if not self.held:
            return []
        return [(f"{len(self.held)} setpoints left out: no START command in the log places "
                 "them in time")]


def _refuse_unless_usable(log: Path, db: Database, seen: _Seen, samples: dict[str, int]) -> None:
    if not seen.decoded:
        ids = ", ".join(f"0x{i:03X}" for i in sorted(seen.ids)[:8])
        raise DataError(f"{log}: none of its {seen.frames} frames decodes as a message of the "
                        f"DBC (ids {ids}{' …' if len(seen.ids) > 8 else ''})")
    missing = [c for c in ("table_u", "mass_x") if not samples.get(c)]
    if not missing:
        return
    found = _found(samples)
    why = {"table_u": "no TableSensor frame",
           "mass_x": f"no {cm.MASS_SENSOR} frame" + (
               "" if cm.MASS_SENSOR in {m.name for m in db.messages} else
               f" (this DBC has no {cm.MASS_SENSOR} message: the rig's mass sensor is on "
               "the serial port, which a CAN log does not hold)")}
    raise DataError(f"{log}: cannot make {' and '.join(missing)}: "
                    f"{'; '.join(why[c] for c in missing)}; found {found}")


def _found(samples: dict[str, int]) -> str:
    """The channels with samples, the actuators' by kind: `table_u (1200 samples), ...`."""
    parts = [f"{c} ({n} samples)" for c, n in samples.items()
             if n and not c.startswith("actuator_")]
    for kind in ("setpoint", "feedback", "status"):
        k = sum(1 for c, n in samples.items() if n and c.startswith(f"actuator_{kind}_"))
        parts += [f"actuator_{kind}_* ({k} actuators)"] if k else []
    return ", ".join(parts) or "no channel"


def _sources(log: Path, db: Database) -> dict[str, str]:
    """The live rig's channel sources, said to come from `log`."""
    where = f"import:{log} can:"
    out = {"table_u": f"{where}0x{cm.TABLE_SENSOR_ID:03X} TableSensor.Counts"}
    mass = [m for m in db.messages if m.name == cm.MASS_SENSOR]
    out["mass_x"] = (f"{where}0x{mass[0].frame_id:03X} {cm.MASS_SENSOR}.Counts" if mass
                     else f"import:{log} (no {cm.MASS_SENSOR} in the DBC)")
    for i in cm.ACTUATORS:
        out[f"actuator_setpoint_{i}"] = (f"{where}0x{cm.SETPOINT_BASE + i:03X} "
                                         f"ActuatorSetpoint{i} at START + index / rate")
        out[f"actuator_feedback_{i}"] = f"{where}0x{cm.FEEDBACK_BASE + i:03X} ActuatorFeedback{i}"
        out[f"actuator_status_{i}"] = (f"{where}0x{cm.FEEDBACK_BASE + i:03X} "
                                       "Status | faults << 4")
    return out


def _config_text(config: RigConfig, log: Path, kind: str) -> str:
    """The configuration file as read (the analysis takes the payload mass from it)."""
    try:
        text = Path(config.source).read_text(encoding="utf-8")
    except OSError:
        text = ""
    return f"# rig import of {log} ({kind})\n{text}"
