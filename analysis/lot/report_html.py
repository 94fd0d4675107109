"""`analysis lot --report DIR`: the spread of each constant across the units and the
lot average's prediction of each, as PNG, on one HTML page with the tables; the units
out of family marked (red) in every figure and table."""

from __future__ import annotations

import html
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from analysis.identify.pipeline import REFINED
from analysis.lot.report import format_lot, us_value
from analysis.lot.schedule import LotResult

OUT, IN = "tab:red", "tab:blue"
STYLE = ("body{font-family:sans-serif;margin:2em}table{border-collapse:collapse}"
         "td,th{border:1px solid #ccc;padding:2px 6px;text-align:right}"
         "tr.out{background:#fdd}tr.failed{background:#eee;color:#666}td.l{text-align:left}")


def write_lot_report(lot: LotResult, directory: Path) -> Path:
    """Write the figures and index.html into `directory`; returns the page's path."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    images = [_spread_figure(lot, directory), _prediction_figure(lot, directory)]
    body = "\n".join(f'<figure><img src="{i.name}" alt="{i.stem}"></figure>' for i in images
                     if i is not None)
    page = directory / "index.html"
    page.write_text("<!doctype html><html><head><meta charset='utf-8'><title>analysis lot"
                    f"</title><style>{STYLE}</style></head><body><h1>Lot of "
                    f"{len(lot.units)} isolators</h1>\n{_table(lot)}\n{body}\n"
                    f"<h2>As text</h2><pre>{html.escape(format_lot(lot))}</pre>\n"
                    "</body></html>\n", encoding="utf-8")
    return page


def _table(lot: LotResult) -> str:
    """One row per unit; out of family red, failed grey, with the reasons."""
    f = lot.family
    rows = [("<table><tr><th>unit</th><th>status</th><th>residual/noise (own)</th>"
             "<th>residual/noise (lot average)</th><th>effects</th><th>verdict</th></tr>")]
    for name, r in lot.units.items():
        if not r.ok:
            rows.append(f"<tr class='failed'><td class='l'>{html.escape(name)}</td><td>failed"
                        f"</td><td></td><td></td><td></td><td class='l'>"
                        f"{html.escape(r.reason)}</td></tr>")
            continue
        v = f.verdicts[name]
        pred = lot.predictions.get(name)
        avg = f"{max(e['residual_over_noise'] for e in pred.values()):.1f}" if pred else ""
        verdict = ("in family" if v.in_family else "OUT: " + "; ".join(v.reasons)) + "".join(
            f" (note: {n})" for n in v.notes)
        rows.append(f"<tr class='{'in' if v.in_family else 'out'}'><td class='l'>"
                    f"{html.escape(name)}</td><td>ok</td>"
                    f"<td>{max(r.residual_over_noise.values()):.2f}</td><td>{avg}</td>"
                    f"<td class='l'>{html.escape(', '.join(r.effects) or '-')}</td>"
                    f"<td class='l'>{html.escape(verdict)}</td></tr>")
    return "\n".join(rows) + "</table>"


def _spread_figure(lot: LotResult, directory: Path) -> Path | None:
    """Per constant: each fitted unit's value ± 95 %, the family's mean ± 1 and 2 std."""
    f = lot.family
    names = [n for n in REFINED if n in f.judged]
    fitted = [r for r in lot.units.values() if r.ok]
    if not names or not fitted:
        return None
    cols = 3
    fig, axes = plt.subplots(int(np.ceil(len(names) / cols)), cols, squeeze=False,
                             figsize=(4.2 * cols, 2.8 * np.ceil(len(names) / cols)))
    x = np.arange(len(fitted))
    out = np.array([not f.verdicts[r.unit].in_family for r in fitted])
    for ax, n in zip(axes.flat, names):
        unit = us_value(1.0, fitted[0].constants[n].unit)[1]
        v = np.array([us_value(r.constants[n].value, r.constants[n].unit)[0] for r in fitted])
        e = np.array([1.96 * us_value(r.constants[n].std or 0.0, r.constants[n].unit)[0]
                      for r in fitted])
        s = (f.spread or f.spread_all)[n]
        mean, std = us_value(s.mean, s.unit)[0], us_value(s.std, s.unit)[0]
        if np.isfinite(std):
            ax.axhspan(mean - 2 * std, mean + 2 * std, color=IN, alpha=0.08)
            ax.axhspan(mean - std, mean + std, color=IN, alpha=0.12)
        ax.axhline(mean, color=IN, lw=0.8)
        ax.errorbar(x[~out], v[~out], e[~out], fmt="o", ms=3, color=IN, label="in family")
        ax.errorbar(x[out], v[out], e[out], fmt="s", ms=5, color=OUT, label="out of family")
        ax.set_title(f"{n} ({unit})", fontsize=10)
        ax.set_xticks(x[out], [fitted[i].unit for i in np.flatnonzero(out)], rotation=60,
                      fontsize=7, color=OUT)
    for ax in list(axes.flat)[len(names):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle("each constant across the lot: family mean, ±1 and ±2 std shaded")
    return _save(fig, directory / "spread.png")


def _prediction_figure(lot: LotResult, directory: Path) -> Path | None:
    names = [u for u in lot.units if u in lot.predictions]
    if not names:
        return None
    own = [max(lot.units[u].residual_over_noise.values()) for u in names]
    avg = [max(e["residual_over_noise"] for e in lot.predictions[u].values()) for u in names]
    out = [not lot.family.verdicts[u].in_family for u in names]
    fig, ax = plt.subplots(figsize=(max(6.0, 0.12 * len(names) + 3), 3.5))
    x = np.arange(len(names))
    ax.bar(x, avg, color=[OUT if o else IN for o in out], alpha=0.7, label="lot average")
    ax.plot(x, own, "k_", ms=8, label="its own fit")
    ax.set(yscale="log", ylabel="residual / sensor noise (worst run)",
           title="how well the lot average predicts each unit")
    ax.set_xticks(x, names, rotation=90, fontsize=6)
    ax.legend(fontsize=8)
    return _save(fig, directory / "prediction.png")


def _save(fig: plt.Figure, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)
    return path
