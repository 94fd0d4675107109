"""The loop on data it has never seen, through the command a user runs.

    python bench/loop_unseen.py [--quick] [--seeds N] [--first K] [--jobs J] [--no-peers]
                                [--only SEED,...] [--out FILE.json]

Campaigns come from `bench/unseen/generator.py`, which shares no code or constants
with the analysis (its own Eq 10 integrator, ramp shapes, effect shapes and sizes,
constants drawn ±30 % around Table 1, noise 0.5–4× the rig's). Each campaign is
written as A.csv, B.csv, C.csv (t, u, x in m) and identified by

    analysis fit A.csv B.csv C.csv --mass 2721.55 --json out.json

in a subprocess, started from nothing the generator knows: the product's path.
Its `effects_added` is scored against the generator's truth:

- exact: the named set is the true set (nothing named on a clean campaign);
- first right: the first effect named is one of the true ones;
- wrong: the first effect named is not one of them;
- missed: an effect was present and nothing was named;
- false positive: something was named on a clean campaign (or for a lagged servo,
  which is the table's motion, not the isolator's).

Also the residual after over the noise where the effect is one of the library's,
how often "unexplained structure" is said, and the wall time per campaign (p50, p90);
then the same per generator effect (`per_effect`), where the time goes (`wall_summary`),
and which stage of the fit it goes to (`stage_table`, from the fit's progress lines).
The peers of `bench/unseen/peers.py` (a stepwise equation-error fit with BIC, and
PySINDy with a dead-band-gated library) are run on the same campaigns as the baseline.

Full run: every effect × N seeds (default 5), clean × 2N, and the pairs below × 2
seeds. `--quick`: every effect and clean, one seed each. `--first K` starts every
effect's seeds at its K-th (clean and pairs from the matching later seeds): a draw the
loop's choices were never made on, to see whether its scores hold out of sample.
"""

from __future__ import annotations

import argparse
import importlib.util
import json
import os
import re
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from analysis.simulate.compiled import warm_up
from bench.unseen import peers  # pysindy is imported only when its peer runs
from bench.unseen.generator import MASS, make_campaign, write_campaign
from bench.unseen.peers import EFFECT_NAMES as PEER_NAMES

# generator effect -> the product's vocabulary; a lagged servo is the table's own motion:
# the isolator model lacks nothing
EFFECT_NAMES = {**PEER_NAMES, "servo_lag": None}
PAIRS = (("coulomb", "hardening"), ("orifice", "force_offset"), ("sensor_delay", "preload"),
         ("asym_stiffness", "thermal"), ("bouc_wen", "sensor_gain"), ("asym_damping", "coulomb"))
TIMEOUT = 600.0  # s per campaign: past it the campaign counts as missed

# the fit's progress lines (stderr) -> the stage that starts there; an indented line
# that no pattern claims continues the stage before it ("  held …", "  F_break: …")
PROGRESS = re.compile(r"^analysis fit \[\s*[\d.]+ s\] (.*)$")
# the loop's work (`analysis.loop.budget`), said on its last progress line
LOOP_WORK = re.compile(r"^loop: done in (\d+) M RK4 steps")
STAGES = (
    (r"(differentiating|appendix A|variable projection)", "identification: equation error"),
    (r"output error: all runs|output error: the table channel", "identification: joint fit"),
    (r"  residual .* again from alpha", "identification: other alpha starts"),
    (r"  residual .* again from run", "identification: a run's own start"),
    (r"run \w+: ", "identification: each run alone"),
    (r"loop: (refitting the base model|the model without)", "loop: base refit"),
    (r"loop: (equation error|residual .* trying equation)", "loop: naming"),
    (r"loop: refitting with .* dead band, which the fit closed", "loop: dead band reopened"),
    (r"loop: refitting with", "loop: candidate refit"),
    (r"loop: (validating|is .* still needed)", "loop: validation"),
    (r"loop: the final fit stopped", "loop: final fit carried on"),
    (r"figures", "report"),
)
START_UP = "start-up, reading the files"


def campaigns(quick: bool, seeds: int, first: int = 1) -> list[tuple[int, tuple[str, ...]]]:
    """(seed, effects) of every campaign; seeds differ per effect so plants differ too.
    From `first` on: effect i's seeds are 100 (i + 1) + first …, clean 2 first − 1 …,
    pair j's 5000 + 100 j + 2 first − 1 and the next (first = 1: the committed draw)."""
    if not (1 <= first <= 49 and first + seeds <= 100):
        # past them a seed would fall in the next effect's or pair's hundred
        raise ValueError(f"first must lie in 1 … {min(49, 100 - seeds)} for {seeds} seeds")
    out: list[tuple[int, tuple[str, ...]]] = []
    n = 1 if quick else seeds
    for i, e in enumerate(EFFECT_NAMES):
        out += [(100 * (i + 1) + s, (e,)) for s in range(first, first + n)]
    c0 = 2 * first - 1
    out += [(s, ()) for s in range(c0, c0 + (1 if quick else 2 * seeds))]
    if not quick:
        for i, pair in enumerate(PAIRS):
            out += [(5000 + 100 * i + s, pair) for s in (c0, c0 + 1)]
    return out


def truth_names(effects: tuple[str, ...]) -> list[str]:
    return [n for e in effects if (n := EFFECT_NAMES[e])]


def stage_of(message: str) -> str | None:
    """The stage a progress message starts, or None where it continues the last one."""
    for pattern, stage in STAGES:
        if re.match(pattern, message):
            return stage
    return None


def stage_seconds(lines: list[tuple[float, str]], wall: float) -> dict[str, float]:
    """Seconds per stage from (time since start, progress message) pairs: each stage
    lasts until the next one starts, the last until the process ends."""
    out: dict[str, float] = {}
    stage, since = START_UP, 0.0
    for t, message in lines:
        new = stage_of(message)
        if new is None or new == stage:
            continue
        out[stage] = out.get(stage, 0.0) + t - since
        stage, since = new, t
    out[stage] = out.get(stage, 0.0) + wall - since
    return out


def run_product(seed: int, effects: tuple[str, ...], work: Path) -> dict:
    """`analysis fit` on one campaign's CSV files: named effects, residuals, wall time,
    and the seconds each stage of the fit took (its progress lines, timed as they come)."""
    c = make_campaign(seed, effects)
    d = work / f"{seed}-{'+'.join(effects) or 'clean'}"
    write_campaign(c, d)
    files = [str(d / f"{r}.csv") for r in "ABC"]
    t0 = time.perf_counter()
    lines: list[tuple[float, str]] = []
    last = ""  # the last line said: the error, where the fit fails
    with (d / "fit.txt").open("w") as stdout:
        proc = subprocess.Popen(["analysis", "fit", *files, "--mass", str(MASS),
                                 "--json", str(d / "out.json")], stdout=stdout,
                                stderr=subprocess.PIPE, text=True,
                                env={**os.environ, "OMP_NUM_THREADS": "1"})
        timer = threading.Timer(TIMEOUT, proc.kill)
        timer.start()
        for line in proc.stderr:
            if m := PROGRESS.match(line.rstrip("\n")):
                lines.append((time.perf_counter() - t0, m.group(1)))
            last = line.strip() or last
        proc.wait()
        timer.cancel()
    wall = time.perf_counter() - t0
    if wall >= TIMEOUT:
        return {"named": [], "wall": TIMEOUT, "error": "timeout"}
    if proc.returncode != 0:
        return {"named": [], "wall": wall, "error": [last]}
    out = json.loads((d / "out.json").read_text())
    return {"named": list(out.get("effects_added", [])), "wall": wall,
            "residual_after": out.get("residual_after", {}).get("residual_over_noise"),
            "residual_before": out.get("residual_before", {}).get("residual_over_noise"),
            "unexplained": bool(out.get("unexplained", {}).get("value", False)),
            # the effects the fit itself reports its runs cannot tell from its own terms
            "not_testable": [c["candidate"] for c in out.get("conditioning", [])
                             if c.get("indistinguishable")],
            "stages": stage_seconds(lines, wall),
            "loop_rk4_steps_M": next((int(w.group(1)) for _, m in lines
                                      if (w := LOOP_WORK.match(m))), None)}


def run_peer(name: str, seed: int, effects: tuple[str, ...]) -> dict:
    c = make_campaign(seed, effects)
    t0 = time.perf_counter()
    named = getattr(peers, name)(c.runs, MASS)
    return {"named": list(named), "wall": time.perf_counter() - t0}


def score(rows: list[dict]) -> dict:
    """Counts of the classes above, and the residual and wall-time figures."""
    out = {"campaigns": len(rows), "exact": 0, "first_right": 0, "wrong": 0, "missed": 0,
           "false_positive": 0, "clean": 0, "with_effect": 0}
    resid, walls, unexplained = [], [], 0
    out["missed_not_testable"] = 0
    for r in rows:
        truth, named = set(r["truth"]), r["named"]
        out["exact"] += set(named) == truth
        # missed, nothing named wrongly, and every missed effect one the fit itself said
        # these runs cannot tell from its own terms (a preload beside k2 tanh(αz))
        missing = truth - set(named)
        out["missed_not_testable"] += bool(missing) and set(named) <= truth and \
            missing <= set(r.get("not_testable", ()))
        walls.append(r["wall"])
        unexplained += bool(r.get("unexplained"))
        if not truth:
            out["clean"] += 1
            out["false_positive"] += bool(named)
            continue
        out["with_effect"] += 1
        if not named:
            out["missed"] += 1
        elif named[0] in truth:
            out["first_right"] += 1
        else:
            out["wrong"] += 1
        if r.get("residual_after") is not None:
            resid.append(r["residual_after"])
    out["residual_after_p50"] = float(np.median(resid)) if resid else None
    out["residual_after_max"] = float(np.max(resid)) if resid else None
    out["residual_within_1_3"] = int(sum(v <= 1.3 for v in resid))  # the bound
    out["unexplained"] = unexplained
    w = np.array(walls)
    out["wall_p50_s"] = float(np.median(w))
    out["wall_p90_s"] = float(np.percentile(w, 90))
    # where the time goes: nothing to name or an effect, the 5 s and 15 s
    nothing = [r["wall"] for r in rows if not r["truth"]]
    effect = [r["wall"] for r in rows if r["truth"]]
    out["wall_p50_nothing_s"] = float(np.median(nothing)) if nothing else None
    out["wall_p50_effect_s"] = float(np.median(effect)) if effect else None
    out["within_5_s"], out["within_15_s"] = int((w <= 5).sum()), int((w <= 15).sum())
    longest = max(rows, key=lambda r: r["wall"])
    out["wall_longest_s"], out["wall_longest_seed"] = float(longest["wall"]), longest["seed"]
    out["wall_total_s"] = float(w.sum())
    return out


def table(results: dict[str, dict]) -> str:
    head = ("| method | exact | first right | wrong | missed | false positive (clean) | "
            "residual after / noise p50 (max) | residual after ≤ 1.3 × noise | "
            "wall p50 / p90 |")
    lines = [head, "|" + "---|" * 9]
    for name, s in results.items():
        res = ("" if s.get("residual_after_p50") is None else
               f"{s['residual_after_p50']:.2f} ({s['residual_after_max']:.2f})")
        within = "" if not res else f"{s['residual_within_1_3']}/{s['with_effect']}"
        lines.append(f"| {name} | {s['exact']}/{s['campaigns']} | {s['first_right']}/"
                     f"{s['with_effect']} | {s['wrong']} | {s['missed']} | "
                     f"{s['false_positive']}/{s['clean']} | {res} | {within} | "
                     f"{s['wall_p50_s']:.1f} s / {s['wall_p90_s']:.1f} s |")
    return "\n".join(lines)


def per_effect(rows: list[dict]) -> str:
    """Exact / seeds and the residual after over the noise of each seed, per generator
    effect or pair (clean campaigns together)."""
    groups: dict[str, list[dict]] = {}
    for r in rows:
        groups.setdefault(" + ".join(r["effects"]) or "clean", []).append(r)
    lines = ["| generator effect | exact | residual after / noise, each seed |", "|---|---|---|"]
    for name, rs in groups.items():
        cells = []
        for r in rs:
            cell = "—" if r.get("residual_after") is None else f"{r['residual_after']:.2f}"
            if r.get("error"):
                cell += f" ({r['error'] if isinstance(r['error'], str) else 'failed'})"
            elif set(r["named"]) != set(r["truth"]):
                cell += f" ({' + '.join(r['named']) or 'nothing named'})"
            cells.append(cell)
        exact = sum(set(r["named"]) == set(r["truth"]) for r in rs)
        lines.append(f"| {name} | {exact}/{len(rs)} | {', '.join(cells)} |")
    return "\n".join(lines)


def wall_summary(s: dict) -> str:
    """Where the time goes, from `score`'s figures."""
    parts = [f"wall p50 {s['wall_p50_nothing_s']:.1f} s with nothing to name"
             if s["wall_p50_nothing_s"] is not None else "",
             f"{s['wall_p50_effect_s']:.1f} s with an effect"
             if s["wall_p50_effect_s"] is not None else "",
             f"{s['within_5_s']} of {s['campaigns']} within 5 s, {s['within_15_s']} within 15 s",
             f"longest {s['wall_longest_s']:.0f} s (seed {s['wall_longest_seed']})",
             f"{s['wall_total_s']:.0f} s in all"]
    return "; ".join(p for p in parts if p)


def stage_table(rows: list[dict]) -> str:
    """Seconds per stage over every campaign, its share of all, and its p50 over the
    campaigns that ran it."""
    per: dict[str, list[float]] = {}
    for r in rows:
        for stage, sec in r.get("stages", {}).items():
            per.setdefault(stage, []).append(sec)
    total = sum(sum(v) for v in per.values())
    if not total:
        return ""
    lines = ["| stage | campaigns | s in all | share | p50 where run |", "|---|---|---|---|---|"]
    order = [START_UP, *dict.fromkeys(stage for _, stage in STAGES)]
    for stage in sorted(per, key=order.index):
        v = per[stage]
        lines.append(f"| {stage} | {len(v)} | {sum(v):.0f} | {100 * sum(v) / total:.0f} % | "
                     f"{np.median(v):.1f} s |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="one seed of every effect and clean")
    ap.add_argument("--seeds", type=int, default=5, help="seeds per effect (default 5)")
    ap.add_argument("--first", type=int, default=1,
                    help="each effect's first seed (default 1); later ones are a held-out draw")
    ap.add_argument("--jobs", type=int, default=2, help="campaigns identified at once")
    ap.add_argument("--no-peers", action="store_true", help="skip the peer baselines")
    ap.add_argument("--out", type=Path, help="write every row and the scores as JSON")
    ap.add_argument("--only", type=lambda s: {int(v) for v in s.split(",")}, default=None,
                    metavar="SEED,...", help="just these campaigns of the full set (by seed)")
    a = ap.parse_args(argv)
    try:
        todo = campaigns(a.quick, a.seeds, a.first)
    except ValueError as e:
        ap.error(str(e))
    if a.only is not None:
        todo = [(s, e) for s, e in todo if s in a.only]
        if not todo:
            ap.error(f"no campaign has seed {sorted(a.only)}; see campaigns() for the numbering")
    if not a.no_peers and importlib.util.find_spec("pysindy") is None:
        # checked before the campaigns, not after them: a missing peer must not cost a run
        ap.error("the peers need PySINDy: pip install -e '.[bench]', or pass --no-peers")
    print(f"{len(todo)} campaigns from bench/unseen/generator.py, {a.jobs} at a time")
    # numba's one-time compile on a cold cache (~40 s) is no campaign's wall time
    warm_up(lambda m: print(f"{m} before the first campaign", flush=True))
    rows: dict[str, list[dict]] = {"analysis fit": []}
    with tempfile.TemporaryDirectory() as tmp, ThreadPoolExecutor(a.jobs) as pool:
        futures = [(seed, eff, pool.submit(run_product, seed, eff, Path(tmp)))
                   for seed, eff in todo]
        for k, (seed, eff, f) in enumerate(futures, 1):
            r = {"seed": seed, "effects": list(eff), "truth": truth_names(eff), **f.result()}
            rows["analysis fit"].append(r)
            print(f"[{k}/{len(todo)}] seed {seed} {'+'.join(eff) or 'clean'}: named "
                  f"{r['named'] or 'nothing'}, residual {r.get('residual_after') or 0:.2f} x "
                  f"noise, {r['wall']:.1f} s"
                  + (f", loop {r['loop_rk4_steps_M']} M RK4 steps"
                     if r.get("loop_rk4_steps_M") is not None else "")
                  + (f" ({r['error']})" if "error" in r else ""),
                  flush=True)
    if not a.no_peers:
        for peer in ("stepwise_bic", "sindy_gated"):
            rows[peer] = [{"seed": s, "effects": list(e), "truth": truth_names(e),
                           **run_peer(peer, s, e)} for s, e in todo]
    results = {name: score(r) for name, r in rows.items()}
    print(table(results))
    print(f"not exact only by effects the fit reports not testable with these runs: "
          f"{results['analysis fit']['missed_not_testable']}")
    print()
    print(per_effect(rows["analysis fit"]))
    print(wall_summary(results["analysis fit"]))
    print()
    print(stage_table(rows["analysis fit"]))
    if a.out:
        a.out.write_text(json.dumps({"scores": results, "rows": rows}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
