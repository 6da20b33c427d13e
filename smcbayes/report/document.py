"""A small format-neutral document model: sections of paragraphs, tables, figures, code.

The report is assembled once as :class:`Section` objects and rendered to HTML and
Markdown from the same content, so the two files never disagree.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


@dataclass(frozen=True)
class Paragraph:
    """Plain text (escaped by the renderers); ``tone`` ``"warning"`` highlights it."""

    text: str
    tone: str = "normal"


@dataclass(frozen=True)
class Heading:
    """A sub-heading inside a section."""

    text: str


@dataclass(frozen=True)
class Bullets:
    """An unordered list of plain-text items."""

    items: tuple[str, ...]
    tone: str = "normal"


@dataclass(frozen=True)
class Table:
    """A table of plain-text cells; ``numeric`` columns are right-aligned."""

    header: tuple[str, ...]
    rows: tuple[tuple[str, ...], ...]
    caption: str = ""
    numeric: tuple[int, ...] = ()


@dataclass(frozen=True)
class Figure:
    """A figure file (PNG; the SVG twin sits next to it) and its caption."""

    path: Path
    caption: str


@dataclass(frozen=True)
class Code:
    """Preformatted text (command lines)."""

    text: str


Block = Heading | Paragraph | Bullets | Table | Figure | Code


@dataclass
class Section:
    """A titled section; ``key`` is its stable anchor (``data``, ``calibration``, ...)."""

    key: str
    title: str
    blocks: list[Block] = field(default_factory=list)

    def add(self, *blocks: Block) -> Section:
        """Append blocks; returns the section for chaining."""
        self.blocks.extend(blocks)
        return self


def fmt(value: object, digits: int = 4) -> str:
    """A number for a table: ``digits`` significant digits, '-' for missing or NaN."""
    if value is None:
        return "-"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if value != value:
            return "-"
        return f"{value:.{digits}g}"
    return str(value)


def pct(value: object) -> str:
    """A share (0..1) as a whole percentage, '-' when missing."""
    if not isinstance(value, (int, float)) or value != value:
        return "-"
    return f"{100.0 * float(value):.0f} %"
