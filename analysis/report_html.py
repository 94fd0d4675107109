"""Building blocks of the self-contained HTML reports: escaped text, tables, figures
embedded as data, values in either unit system, and the page around them.

A report is forwarded as one file: every figure is inside it as a base64 PNG and the
style is inline, so nothing outside the file is ever fetched and it prints as shown.
Every piece of text goes through `esc`; pieces already built here are `Html`, which
passes through unchanged, so text is escaped once and markup never.
"""

from __future__ import annotations

import base64
import html
from collections.abc import Collection, Iterable, Sequence
from pathlib import Path

from rig.units import US_FOR_SI, from_si, us_unit

STYLE = """
body{font-family:system-ui,sans-serif;margin:2em auto;max-width:62em;color:#222;line-height:1.4}
h1{margin-bottom:.2em}h2{border-bottom:1px solid #ccc;margin-top:2em}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}
caption{text-align:left;font-weight:600;padding:.3em 0}
th,td{border:1px solid #ccc;padding:2px 7px;text-align:right;vertical-align:top}
th{background:#f3f3f3;white-space:nowrap}td.text,th.text{text-align:left}
tr.held td{background:#fff8e0}.warn{color:#a00;font-weight:600}
figure{margin:1em 0}figure img{max-width:100%;height:auto;border:1px solid #eee}
figcaption{font-size:.9em;color:#444}.file{color:#777;font-family:monospace}
dl.facts{display:grid;grid-template-columns:max-content auto;gap:.1em 1em}
dl.facts dt{font-weight:600}dl.facts dd{margin:0}
pre{background:#f7f7f7;padding:.8em;overflow-x:auto;font-size:.8em}
@media print{body{margin:0;max-width:none}figure,table,tr{break-inside:avoid}
h2,h3{break-after:avoid}nav{display:none}pre{white-space:pre-wrap}}
"""


class Html(str):
    """Markup built by this module: not escaped again."""


def esc(value: object) -> Html:
    """`value` as HTML text: escaped, unless it is already `Html`."""
    return value if isinstance(value, Html) else Html(html.escape(str(value)))


def _attrs(cls: str, attrs: dict[str, str]) -> str:
    # a trailing underscore frees a Python keyword (for_); other underscores are hyphens
    pairs = ([("class", cls)] if cls else []) + [(k.rstrip("_").replace("_", "-"), v)
                                                 for k, v in attrs.items()]
    return "".join(f' {k}="{esc(v)}"' for k, v in pairs)


def tag(name: str, *content: object, cls: str = "", **attrs: str) -> Html:
    """<name class=… attrs…>content</name>, every piece of text escaped."""
    return Html(f"<{name}{_attrs(cls, attrs)}>{''.join(esc(c) for c in content)}</{name}>")


def table(head: Sequence[object], rows: Iterable[Sequence[object]], caption: str = "",
          text: Collection[int] = (0,), row_classes: Sequence[str] = (), cls: str = "") -> Html:
    """A table: `head` cells, then each row; columns `text` (indices, -1 the last) are
    words, left-aligned; the rest numbers, right-aligned."""
    def cells(row: Sequence[object], cell: str) -> Html:
        left = {i % len(row) for i in text} if row else set()
        return Html("".join(tag(cell, c, cls="text" if i in left else "")
                            for i, c in enumerate(row)))

    body = [tag("tr", cells(head, "th"))]
    for i, row in enumerate(rows):
        body.append(tag("tr", cells(row, "td"),
                        cls=row_classes[i] if i < len(row_classes) else ""))
    return tag("table", tag("caption", caption) if caption else "", *body, cls=cls)


def facts(pairs: Iterable[tuple[object, object]]) -> Html:
    """Label: value pairs, as a definition list."""
    return tag("dl", Html("".join(tag("dt", k) + tag("dd", v) for k, v in pairs)), cls="facts")


def bullets(items: Iterable[object]) -> Html:
    return tag("ul", Html("".join(tag("li", i) for i in items)))


def figure(png: Path, caption: str) -> Html:
    """The PNG inside the page as data (the file beside it stays for those who link it)."""
    data = base64.b64encode(Path(png).read_bytes()).decode("ascii")
    img = Html(f'<img src="data:image/png;base64,{data}" alt="{esc(caption)}">')
    return tag("figure", img, tag("figcaption", caption, " ",
                                  tag("span", f"({Path(png).name})", cls="file")))


def section(anchor: str, title: str, *content: object) -> Html:
    return tag("section", tag("h2", title), *content, id=anchor)


def page(title: str, body: Sequence[object]) -> str:
    """The whole document: inline style, no scripts, nothing fetched from outside."""
    return ("<!doctype html>\n<html lang='en'><head><meta charset='utf-8'>"
            f"<title>{esc(title)}</title><style>{STYLE}</style></head>\n<body>\n"
            + "\n".join(esc(b) for b in body) + "\n</body></html>\n")


def in_units(value: float, si_unit: str, units: str) -> tuple[float, str]:
    """An SI value in `units` ("us": the report's in, lb, s; "si"); a unit the report
    has no name for stays SI."""
    if units == "si" or si_unit not in US_FOR_SI:
        return value, si_unit
    u = us_unit(si_unit)
    return float(from_si(value, u)), u


def num(value: float | None, spec: str = ".4g") -> str:
    """A number to the CLI's significant digits, without its exponent where a person
    reads the plain number more easily (73090, not 7.309e+04); blank for none."""
    if value is None:
        return ""
    text = format(value, spec)
    if "e" in text and 1e-4 <= abs(value) < 1e7:
        text = f"{float(text):f}".rstrip("0").rstrip(".")
    return text


def percent(fraction: float | None) -> str:
    """A fraction as the CLI prints an error: 0.0123 → 1.23 %; blank for none."""
    return "" if fraction is None else f"{100 * fraction:.2f} %"
