"""Render a list of :class:`~smcbayes.report.document.Section` as HTML or Markdown.

HTML is one self-contained file: CSS inline, figures embedded as base64 PNG, no script
and no external resource, so it opens offline, prints and archives as one file.  The
Markdown twin references the figures by paths relative to the report file.
"""

from __future__ import annotations

import base64
import os
from collections.abc import Sequence
from html import escape
from pathlib import Path

from smcbayes.report.document import Bullets, Code, Figure, Heading, Paragraph, Section, Table

CSS = """
body { font-family: system-ui, -apple-system, 'Segoe UI', Roboto, sans-serif; color: #1a1a1a;
       max-width: 62rem; margin: 0 auto; padding: 1rem 1.5rem 3rem; line-height: 1.45; }
h1 { font-size: 1.6rem; margin-bottom: 0.2rem; }
h2 { font-size: 1.3rem; border-bottom: 2px solid #ccc; padding-bottom: 0.2rem; margin-top: 2.2rem; }
h3 { font-size: 1.05rem; margin-top: 1.4rem; }
nav ul { padding-left: 1.2rem; columns: 2; }
table { border-collapse: collapse; margin: 0.6rem 0 1rem; font-size: 0.88rem; }
caption { caption-side: top; text-align: left; font-style: italic; padding-bottom: 0.2rem; }
th, td { border: 1px solid #bbb; padding: 0.2rem 0.5rem; vertical-align: top; }
th { background: #eef1f5; text-align: left; }
td.num { text-align: right; font-variant-numeric: tabular-nums; }
figure { margin: 1rem 0; page-break-inside: avoid; break-inside: avoid; }
figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption { font-size: 0.88rem; color: #444; }
pre { background: #f4f4f4; padding: 0.6rem; overflow-x: auto; font-size: 0.8rem;
      white-space: pre-wrap; }
.scroll { overflow-x: auto; }
.warning { background: #fff4e0; border-left: 4px solid #e09000; padding: 0.3rem 0.6rem; }
.meta { color: #555; font-size: 0.9rem; }
@media print { body { max-width: none; padding: 0; font-size: 10pt; } nav { display: none; }
  h2 { page-break-after: avoid; break-after: avoid; } table, pre { page-break-inside: avoid; }
  .scroll { overflow: visible; } table { font-size: 8pt; } }
"""


def _png_data(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def _html_table(t: Table) -> str:
    head = "".join(f"<th>{escape(h)}</th>" for h in t.header)
    body = []
    for row in t.rows:
        cells = "".join(
            f'<td class="num">{escape(c)}</td>' if i in t.numeric else f"<td>{escape(c)}</td>"
            for i, c in enumerate(row)
        )
        body.append(f"<tr>{cells}</tr>")
    caption = f"<caption>{escape(t.caption)}</caption>" if t.caption else ""
    return (
        f'<div class="scroll"><table>{caption}<thead><tr>{head}</tr></thead>'
        f"<tbody>{''.join(body)}</tbody></table></div>"
    )


def _html_block(b: object) -> str:
    if isinstance(b, Heading):
        return f"<h3>{escape(b.text)}</h3>"
    if isinstance(b, Paragraph):
        cls = ' class="warning"' if b.tone == "warning" else ""
        return f"<p{cls}>{escape(b.text)}</p>"
    if isinstance(b, Bullets):
        cls = ' class="warning"' if b.tone == "warning" else ""
        return f"<ul{cls}>" + "".join(f"<li>{escape(i)}</li>" for i in b.items) + "</ul>"
    if isinstance(b, Table):
        return _html_table(b)
    if isinstance(b, Figure):
        return (
            f'<figure><img src="{_png_data(b.path)}" alt="{escape(b.caption)}">'
            f"<figcaption>{escape(b.caption)}</figcaption></figure>"
        )
    if isinstance(b, Code):
        return f"<pre>{escape(b.text)}</pre>"
    raise TypeError(f"unknown report block {type(b).__name__}")


def to_html(title: str, subtitle: str, sections: Sequence[Section]) -> str:
    """One self-contained HTML page."""
    nav = "".join(f'<li><a href="#{s.key}">{escape(s.title)}</a></li>' for s in sections)
    parts = [
        "<!DOCTYPE html>",
        '<html lang="en"><head><meta charset="utf-8">',
        '<meta name="viewport" content="width=device-width, initial-scale=1">',
        f"<title>{escape(title)}</title><style>{CSS}</style></head><body>",
        f"<h1>{escape(title)}</h1>",
        f'<p class="meta">{escape(subtitle)}</p>',
        f"<nav><ul>{nav}</ul></nav>",
    ]
    for s in sections:
        parts.append(f'<section id="{s.key}"><h2>{escape(s.title)}</h2>')
        parts.extend(_html_block(b) for b in s.blocks)
        parts.append("</section>")
    parts.append("</body></html>")
    return "\n".join(parts) + "\n"


def _md_cell(text: str) -> str:
    return text.replace("|", "\\|").replace("\n", " ")


def _md_block(b: object, base: Path) -> str:
    if isinstance(b, Heading):
        return f"### {b.text}"
    if isinstance(b, Paragraph):
        return f"> **Warning:** {b.text}" if b.tone == "warning" else b.text
    if isinstance(b, Bullets):
        prefix = "**Warning:** " if b.tone == "warning" else ""
        return "\n".join(f"- {prefix}{i}" for i in b.items)
    if isinstance(b, Table):
        lines = [f"*{b.caption}*", ""] if b.caption else []
        lines.append("| " + " | ".join(_md_cell(h) for h in b.header) + " |")
        lines.append(
            "|" + "|".join("---:" if i in b.numeric else "---" for i in range(len(b.header))) + "|"
        )
        lines += ["| " + " | ".join(_md_cell(c) for c in row) + " |" for row in b.rows]
        return "\n".join(lines)
    if isinstance(b, Figure):
        rel = Path(os.path.relpath(b.path, base)).as_posix()
        svg = Path(rel).with_suffix(".svg").as_posix()
        return f"![{b.caption}]({rel})\n\n*{b.caption}* (SVG: `{svg}`)"
    if isinstance(b, Code):
        return f"```\n{b.text}\n```"
    raise TypeError(f"unknown report block {type(b).__name__}")


def to_markdown(title: str, subtitle: str, sections: Sequence[Section], base: Path) -> str:
    """Markdown with figures referenced relative to ``base`` (the report's folder)."""
    parts = [f"# {title}", "", subtitle, ""]
    parts += [f"- [{s.title}](#{s.key})" for s in sections] + [""]
    for s in sections:
        parts += [f'<a id="{s.key}"></a>', "", f"## {s.title}", ""]
        for b in s.blocks:
            parts += [_md_block(b, base), ""]
    return "\n".join(parts)
