"""Parse a report HTML page with the standard library and collect what the tests check."""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from html.parser import HTMLParser

PLACEHOLDER = re.compile(r"\{\{|\}\}|\{[A-Za-z_][A-Za-z0-9_.]*\}|\$\{|<%|%>")


@dataclass
class PageFacts:
    """Sections, figures, references and visible text of a page."""

    sections: list[str] = field(default_factory=list)
    img_src: list[str] = field(default_factory=list)
    inline_svg: int = 0
    references: list[tuple[str, str, str]] = field(default_factory=list)
    stylesheets: list[str] = field(default_factory=list)
    scripts: int = 0
    text: list[str] = field(default_factory=list)


class _Parser(HTMLParser):
    def __init__(self) -> None:
        super().__init__(convert_charrefs=True)
        self.facts = PageFacts()

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = {k: v or "" for k, v in attrs}
        if tag == "section" and a.get("id"):
            self.facts.sections.append(a["id"])
        if tag == "img":
            self.facts.img_src.append(a.get("src", ""))
        if tag == "svg":
            self.facts.inline_svg += 1
        if tag == "script":
            self.facts.scripts += 1
        if tag == "link" and "stylesheet" in a.get("rel", ""):
            self.facts.stylesheets.append(a.get("href", ""))
        for key in ("src", "href", "data", "srcset", "poster", "action"):
            if key in a:
                self.facts.references.append((tag, key, a[key]))

    def handle_data(self, data: str) -> None:
        self.facts.text.append(data)


def parse_page(text: str) -> PageFacts:
    """Facts of an HTML page (raises nothing on odd markup; html.parser is lenient)."""
    p = _Parser()
    p.feed(text)
    p.close()
    return p.facts


def external_references(facts: PageFacts) -> list[tuple[str, str, str]]:
    """References that would need a network or a file next to the page."""
    bad = []
    for tag, key, value in facts.references:
        v = value.strip().lower()
        if v.startswith("#") or v.startswith("data:"):
            continue
        bad.append((tag, key, value))
    return bad
