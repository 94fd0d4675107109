"""Benchmark of acquisition: the highest CAN frame rate the rig logs with zero loss while the
mass sensor streams 5,760 serial frames/s (16-byte frames at 921,600 baud), and the rig's CPU.

    python bench/acquisition.py [--seconds 3] [--rates 2000,4000,6000,8000,9000,10000]

A source process (this file with --source RATE) serves the socketcand bus with a device
sending TableSensor frames at RATE and a PtySensor at 5,760 frames/s. This process logs
them as a run does: rig.run.receive receivers, rig.run.recorder.Recorder, rig.runfile.RunWriter.
Baseline, measured in the same run at the same rates: a bare receive loop (python-can
recv + serial read, no decoding, no file). The ratio rig CPU / baseline CPU is what
decoding and logging cost; losses come from the sensors' sequence counters.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import replace
from pathlib import Path
from types import MappingProxyType

SERIAL_RATE = 5760.0


def source(rate: float) -> None:
    """The far side, until stdin closes: rate > 0 a bus with a table-sensor flood at `rate`;
    rate < 0 the serial sensor (its own process, so neither starves the other of the GIL)."""
    from sim.devices import table_sample
    from sim.pty_sensor import PtySensor
    from sim.socketcand_server import SocketcandServer

    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    if rate < 0:
        with PtySensor(lambda t: 0.0, rate_hz=SERIAL_RATE) as pty:
            print(json.dumps({"pty": pty.path}), flush=True)
            stop.wait()
        return
    with SocketcandServer() as server:
        print(json.dumps({"port": server.port}), flush=True)
        t0, k = time.monotonic(), 0
        while not stop.wait(0.001):
            due = int((time.monotonic() - t0) * rate)
            if due > k:
                server.broadcast_many([table_sample(0, i, i) for i in range(k, due)])
                k = due


def measure(rate: float, seconds: float, logging: bool) -> dict:
    from rig.config import load_config
    from rig.run.receive import Receivers, open_bus, open_port
    from rig.run.recorder import Recorder
    from rig.runfile import RunInfo, RunWriter

    sources = [subprocess.Popen([sys.executable, __file__, "--source", str(r)],
                                stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
               for r in (rate, -1.0)]
    try:
        ends = {k: v for s in sources for k, v in json.loads(s.stdout.readline()).items()}
        config = load_config()
        config = replace(config, backend="hardware",
                         can=replace(config.can, extra=MappingProxyType(
                             dict(config.can.extra, port=ends["port"]))),
                         serial=replace(config.serial, path=ends["pty"]))
        bus, port = open_bus(config), open_port(config)
        with tempfile.TemporaryDirectory() as tmp:
            writer = RunWriter(Path(tmp) / "bench.h5", RunInfo("bench", "", "sim"))
            rec = Recorder(writer, config, time.time() - writer.elapsed(), writer.t0)
            receivers = Receivers(bus, port)
            counts = {"can": 0, "serial": 0}
            time.sleep(0.5)  # let both streams start before the clock runs
            _drain(receivers, rec if logging else None, counts)
            counts = {"can": 0, "serial": 0}
            lost0 = dict(rec.lost)
            c0, w0 = time.process_time(), time.monotonic()
            while time.monotonic() - w0 < seconds:
                _drain(receivers, rec if logging else None, counts)
                if logging:
                    writer.poll()
                time.sleep(0.001)
            cpu, wall = time.process_time() - c0, time.monotonic() - w0
            receivers.close()
            port.close()
            bus.shutdown()
            writer.close("success")
        lost = {k: rec.lost[k] - lost0[k] for k in lost0} if logging else {}
        return {"rate": rate, "can": counts["can"] / wall, "serial": counts["serial"] / wall,
                "cpu": cpu / wall, "lost": lost}
    finally:
        for s in sources:
            s.stdin.close()
            s.wait(timeout=10)


def _drain(receivers, rec, counts: dict) -> None:
    from rig.run.receive import CanReceived, SerialReceived

    q = receivers.queue
    while not q.empty():
        item = q.get_nowait()
        if isinstance(item, CanReceived):
            counts["can"] += 1
            if rec is not None:
                rec.can_frame(item.frame)
        elif isinstance(item, SerialReceived):
            counts["serial"] += len(item.frames)
            if rec is not None:
                rec.serial_frames(item.host_s, item.frames, item.stats)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--source", type=float, help=argparse.SUPPRESS)
    p.add_argument("--seconds", type=float, default=3.0)
    p.add_argument("--rates", default="2000,4000,6000,8000,9000,10000")
    args = p.parse_args()
    if args.source:
        return source(args.source)
    print(f"CAN TableSensor frames/s logged while serial streams {SERIAL_RATE:,.0f} frames/s "
          f"({args.seconds:g} s each; cores: {os.cpu_count()}, load {os.getloadavg()[0]:.1f})")
    best = 0.0
    for rate in (float(r) for r in args.rates.split(",")):
        base = measure(rate, args.seconds, logging=False)
        rig = measure(rate, args.seconds, logging=True)
        ok = rig["lost"]["can"] == 0 and rig["can"] > 0.97 * rate
        print(f"  {rate:>7,.0f}/s asked: logged {rig['can']:>7,.0f} CAN + {rig['serial']:>6,.0f} "
              f"serial frames/s, lost {rig['lost']['can']} CAN + {rig['lost']['serial']} serial, "
              f"rig CPU {rig['cpu']:.0%} of one core, "
              f"{rig['cpu'] / max(base['cpu'], 1e-9):.2f}x the bare receive loop "
              f"({base['cpu']:.0%}){'' if ok else '  << loss or short'}")
        if not ok:
            break
        best = rate
    print(f"highest rate logged with zero CAN loss: {best:,.0f} CAN frames/s "
          f"(bus maximum 9,009 best case); serial achieved and lost: per row")


if __name__ == "__main__":
    sys.exit(main())
