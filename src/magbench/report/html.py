"""``report.html``: the report as one self-contained page a researcher reads in a browser.

The page is built from the same sections as ``report.md`` (each returns Markdown; a small
converter here handles the subset they write: headings, paragraphs, bullets, tables, images,
emphasis, code and links), with:

- a table of contents and the answer (the decision table) first;
- every table sortable by a click on its header (a few lines of inline JavaScript); the
  query string ``?sort=<table>,<column>[,desc]`` applies one sort on load, which is how a
  headless browser test checks that sorting works;
- every figure embedded as base64 PNG, with the n behind its points, and for the sweeps an
  interactive inline SVG (hover: value and n);
- sub-sections and long tables folded in ``<details>``.

Nothing is fetched: no CDN, no font, no script from elsewhere.
"""

from __future__ import annotations

import base64
import re
from collections.abc import Callable, Sequence
from html import escape
from pathlib import Path

import pandas as pd

from magbench.core.files import write_text_atomic
from magbench.figures.svg import line_chart_svg
from magbench.figures.sweeps import FIGURES

__all__ = ["FIGURE_NOTES", "build_html", "figure_note", "md_to_html", "slug", "write_html"]

#: Tables longer than this are folded (the first rows of a section stay readable).
FOLD_ROWS = 20

_CSS = """
body{font:15px/1.5 system-ui,sans-serif;max-width:1100px;margin:0 auto;padding:0 1em 4em;
color:#222}
h1{margin-top:.6em}h2{border-bottom:1px solid #ccc;margin-top:2em}
nav.toc{background:#f6f6f6;border:1px solid #ddd;padding:.5em 1em;columns:2}
nav.toc ul{margin:0;padding-left:1.2em}
table{border-collapse:collapse;margin:.6em 0;font-size:13px}
th,td{border:1px solid #ccc;padding:2px 6px;vertical-align:top}
th{background:#eee;cursor:pointer;user-select:none;white-space:nowrap}
th[aria-sort=ascending]::after{content:" \\25B2"}th[aria-sort=descending]::after{content:" \\25BC"}
table.decision td:nth-child(2){font-weight:bold}
details{margin:.5em 0;border-left:3px solid #ddd;padding-left:.6em}
summary{cursor:pointer;font-weight:600}
figure{margin:.8em 0}figure img{max-width:100%;height:auto}
figcaption{font-size:13px;color:#444}
code{background:#f3f3f3;padding:0 2px}
svg.chart{max-width:100%;height:auto;font:11px sans-serif}
svg .ct{font-weight:bold}svg circle:hover{r:6}
.prov{font-size:13px;color:#555}
"""

# Sort on a header click (numbers numerically: a cell's first number, '-' last); the query
# string ?sort=T,C[,desc] sorts table T by column C on load (the browser test's hook).
_JS = """
function cellKey(td){var t=td.textContent.trim();var m=t.match(/^-?[0-9.]+(e[-+]?[0-9]+)?/i);
return m?parseFloat(m[0]):(t==='-'?Infinity:t.toLowerCase());}
function sortTable(table,col,desc){var body=table.tBodies[0];var rows=[].slice.call(body.rows);
rows.sort(function(a,b){var x=cellKey(a.cells[col]),y=cellKey(b.cells[col]);
if(typeof x!==typeof y){x=String(x);y=String(y);}return (x<y?-1:x>y?1:0)*(desc?-1:1);});
rows.forEach(function(r){body.appendChild(r);});
[].forEach.call(table.tHead.rows[0].cells,function(th,i){
th.setAttribute('aria-sort',i===col?(desc?'descending':'ascending'):'none');});}
document.addEventListener('DOMContentLoaded',function(){
var tables=document.querySelectorAll('table.sortable');
[].forEach.call(tables,function(table){[].forEach.call(table.tHead.rows[0].cells,
function(th,i){th.addEventListener('click',function(){
sortTable(table,i,th.getAttribute('aria-sort')==='ascending');});});});
var q=new URLSearchParams(location.search).get('sort');
if(q){var p=q.split(',');var t=tables[parseInt(p[0])];
if(t){sortTable(t,parseInt(p[1]),p[2]==='desc');document.body.setAttribute('data-sorted',q);}}
});
"""


def slug(text: str) -> str:
    """An anchor from a heading, as GitHub makes them (lower case, punctuation dropped,
    spaces to hyphens), so the Markdown report's table of contents links the same way."""
    text = re.sub(r"[^\w\- ]", "", text.strip().lower())
    return text.replace(" ", "-")


def _sweep_svgs(csv: Path, sweep: str) -> str:
    data = pd.read_csv(csv)
    spec = FIGURES[sweep]
    parts = [line_chart_svg(data, "accuracy", f"accuracy 1/rho against {spec.x}",
                            logx=spec.logx, logy=True, categorical=spec.categorical),
             line_chart_svg(data, "RB_pct", f"RB % against {spec.x}", logx=spec.logx,
                            categorical=spec.categorical)]
    return ("<details><summary>Interactive: hover a point for its value and n</summary>"
            + "".join(parts) + "</details>")


def _span(values: pd.Series) -> str:
    v = pd.to_numeric(values, errors="coerce").dropna()
    if v.empty:
        return "-"
    lo, hi = int(v.min()), int(v.max())
    return str(lo) if lo == hi else f"{lo}-{hi}"


def _count_note(data: pd.DataFrame) -> str:
    """n per point from a figure's CSV: its n columns, else its distinct runs or trials."""
    cols = [c for c in data.columns if c == "n" or c.startswith("n_")]
    if cols:
        return "; ".join(f"{c} {_span(data[c])}" for c in cols)
    for unit in ("run", "trial", "dataset"):
        if unit in data:
            keys = [c for c in ("method", "algorithm", "x", "series") if c in data]
            counts = data.groupby(keys)[unit].nunique() if keys else pd.Series(
                [data[unit].nunique()])
            return f"{unit}s per point {_span(counts)}"
    return f"one row of the CSV per point ({len(data)} rows)"


#: Figure stem -> extra note: how to read n where the CSV alone does not say it.
FIGURE_NOTES: dict[str, str] = {
    "heading_vs_J": "each point is one unit (one run or recording) of one method: n = 1",
}


def figure_note(image: Path) -> str:
    """The n behind a figure's points, from the CSV drawn beside it ('' without one)."""
    csv = image.with_suffix(".csv")
    note = FIGURE_NOTES.get(image.stem, "")
    if not csv.exists():
        return note
    try:
        data = pd.read_csv(csv)
    except (ValueError, OSError):
        return note
    text = f"n per point ({csv.name}): {_count_note(data)}"
    return f"{text}; {note}" if note else text


def _image(alt: str, src: str, base: Path) -> str:
    path = base / src
    if not path.exists():
        return f"<em>[figure {escape(src)} missing]</em>"
    mime = "svg+xml" if path.suffix == ".svg" else "png"
    data = base64.b64encode(path.read_bytes()).decode()
    caption = escape(alt) + (f" <br>{escape(figure_note(path))}" if figure_note(path) else "")
    extra = ""
    sweep = next((k for k, s in FIGURES.items() if s.stem == path.stem), None)
    if sweep and path.with_suffix(".csv").exists():
        extra = _sweep_svgs(path.with_suffix(".csv"), sweep)
    return (f'<figure><img alt="{escape(alt)}" src="data:image/{mime};base64,{data}">'
            f"<figcaption>{caption}</figcaption>{extra}</figure>")


_CODE = re.compile(r"`([^`]+)`")
_IMG = re.compile(r"!\[([^\]]*)\]\(<?([^)>]+)>?\)")
_LINK = re.compile(r"\[([^\]]+)\]\(([^)]+)\)")
_BOLD = re.compile(r"\*\*(.+?)\*\*")
_EM = re.compile(r"(?<![\w*])\*(?![\s*])(.+?)(?<![\s*])\*(?![\w*])")


def _inline(text: str, base: Path) -> str:
    """Inline Markdown to HTML: code spans first (nothing inside them is markup)."""
    keep: list[str] = []

    def stash(html: str) -> str:
        keep.append(html)
        return f"\x00{len(keep) - 1}\x00"

    text = _CODE.sub(lambda m: stash(f"<code>{escape(m[1])}</code>"), text)
    text = _IMG.sub(lambda m: stash(_image(m[1], m[2], base)), text)
    text = escape(text, quote=False)
    text = _LINK.sub(lambda m: f'<a href="{m[2]}">{m[1]}</a>', text)
    text = _BOLD.sub(r"<strong>\1</strong>", text)
    text = _EM.sub(r"<em>\1</em>", text)
    return re.sub("\x00(\\d+)\x00", lambda m: keep[int(m[1])], text)


def _cells(line: str) -> list[str]:
    return [c.strip() for c in line.strip().strip("|").split("|")]


def _table(lines: list[str], base: Path) -> str:
    head, body = _cells(lines[0]), [_cells(x) for x in lines[2:]]
    html = ('<table class="sortable"><thead><tr>'
            + "".join(f"<th>{_inline(c, base)}</th>" for c in head) + "</tr></thead><tbody>"
            + "".join("<tr>" + "".join(f"<td>{_inline(c, base)}</td>" for c in row)
                      + "</tr>" for row in body) + "</tbody></table>")
    if len(body) > FOLD_ROWS:
        html = (f"<details><summary>Table: {escape(', '.join(head[:3]))}, ... "
                f"({len(body)} rows)</summary>{html}</details>")
    return html


def md_to_html(md: str, base: Path) -> str:
    """The Markdown the report sections write, as HTML (images embedded from ``base``).

    ``##`` headings open a ``<section>``; ``###`` and deeper open a folded ``<details>``
    that runs to the next heading; tables over :data:`FOLD_ROWS` rows are folded too.
    """
    out: list[str] = []
    open_details = open_section = False
    lines = md.split("\n")
    i = 0
    while i < len(lines):
        line = lines[i]
        heading = re.match(r"^(#{1,6}) (.*)$", line)
        if heading:
            level, title = len(heading[1]), heading[2].strip()
            if open_details:
                out.append("</details>")
                open_details = False
            if level <= 2 and open_section:
                out.append("</section>")
                open_section = False
            if level == 2:
                out.append(f'<section id="{slug(title)}"><h2>{_inline(title, base)}</h2>')
                open_section = True
            elif level == 1:
                out.append(f"<h1>{_inline(title, base)}</h1>")
            else:
                out.append(f'<details id="{slug(title)}"><summary>{_inline(title, base)}'
                           "</summary>")
                open_details = True
            i += 1
        elif line.startswith("|"):
            block = []
            while i < len(lines) and lines[i].startswith("|"):
                block.append(lines[i])
                i += 1
            out.append(_table(block, base) if len(block) >= 2 else _inline(block[0], base))
        elif line.startswith("- "):
            items = []
            while i < len(lines) and lines[i].startswith("- "):
                items.append(lines[i][2:])
                i += 1
                while i < len(lines) and lines[i].startswith("  ") and lines[i].strip():
                    items[-1] += " " + lines[i].strip()
                    i += 1
            out.append("<ul>" + "".join(f"<li>{_inline(t, base)}</li>" for t in items)
                       + "</ul>")
        elif line.startswith("<!--"):
            i += 1                 # the Markdown report's markers (format.html_only)
        elif line.strip().startswith("<"):
            out.append(line)       # raw HTML a section wrote for the page (kept as it is)
            i += 1
        elif line.strip():
            para = []
            while (i < len(lines) and lines[i].strip()
                   and not re.match(r"^(#{1,6} |\||- )", lines[i])):
                para.append(lines[i].strip())
                i += 1
            text = _inline(" ".join(para), base)
            out.append(f'<div class="figblock">{text}</div>' if "<figure>" in text
                       else f"<p>{text}</p>")
        else:
            i += 1
    if open_details:
        out.append("</details>")
    if open_section:
        out.append("</section>")
    return "\n".join(out)


def _toc(body: str) -> str:
    """Nested list of the page's sections (h2) and their folded parts (details with ids)."""
    items = re.findall(r'<(section|details) id="([^"]+)"><(?:h2|summary)>(.*?)</(?:h2|summary)>',
                       body)
    tree: list[tuple[str, str, list[tuple[str, str]]]] = []
    for tag, anchor, title in items:
        if tag == "section" or not tree:
            tree.append((anchor, title, []))
        else:
            tree[-1][2].append((anchor, title))
    lis = []
    for anchor, title, subs in tree:
        sub = ("<ul>" + "".join(f'<li><a href="#{a}">{t}</a></li>' for a, t in subs) + "</ul>"
               if subs else "")
        lis.append(f'<li><a href="#{anchor}">{title}</a>{sub}</li>')
    return ('<nav class="toc" id="contents"><strong>Contents</strong><ul>' + "".join(lis)
            + "</ul></nav>")


def section_text(section: Callable[[Path], str], results_dir: Path,
                 texts: dict | None = None) -> str:
    """``section(results_dir)``, computed once per ``texts`` (a report's store, shared by its
    Markdown and its page, which show the same sections); every time without one."""
    if texts is None:
        return section(results_dir)
    if section not in texts:
        texts[section] = section(results_dir)
    return texts[section]


def build_html(results_dir: Path | str, sections: Sequence[Callable[[Path], str]],
               details: dict[Callable[[Path], str], Callable[[Path], str]] | None = None,
               texts: dict | None = None) -> str:
    """The page: every section's Markdown as HTML, the decision table marked, a table of
    contents after the title. ``details`` maps a section to Markdown the page adds under
    it, folded (the reasoning the Markdown report leaves to the page); ``texts`` as in
    :func:`section_text`."""
    results_dir = Path(results_dir)
    details = details or {}
    parts = []
    for section in sections:
        md = section_text(section, results_dir, texts)
        if not md:
            continue
        html = md_to_html(md.strip(), results_dir)
        extra = details.get(section)
        more = section_text(extra, results_dir, texts) if extra else ""
        if more:
            body = md_to_html("\n".join(x for x in more.strip().split("\n")
                                        if not x.startswith("## ")), results_dir)
            fold = f"<details><summary>The reasoning in full</summary>{body}</details>"
            html = (html[:-len("</section>")] + fold + "</section>"
                    if html.endswith("</section>") else html + fold)
        parts.append(html)
    body = "\n".join(parts)
    first = body.find('<section id="in-short')
    if first >= 0:         # the answer table is the first table of that section
        at = body.find('<table class="sortable">', first)
        if at >= 0:
            body = (body[:at] + '<table class="sortable decision" id="decision">'
                    + body[at + len('<table class="sortable">'):])
    title_end = body.find("</h1>")
    toc = _toc(body)
    body = (body[:title_end + 5] + toc + body[title_end + 5:] if title_end >= 0
            else toc + body)
    return ("<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
            "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
            "<title>magbench report</title>"
            f"<style>{_CSS}</style><script>{_JS}</script></head><body>\n{body}\n"
            "</body></html>\n")


def write_html(results_dir: Path | str, sections: Sequence[Callable[[Path], str]],
               details: dict | None = None, texts: dict | None = None) -> Path:
    """Write ``<results_dir>/report.html`` (see :func:`build_html`)."""
    path = Path(results_dir) / "report.html"
    write_text_atomic(build_html(results_dir, sections, details, texts), path)
    return path
