"""Rendering of the document model: escaping, embedding, Markdown tables and paths."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from smcbayes.plotting import pyplot, save
from smcbayes.report.document import (
    Bullets,
    Code,
    Figure,
    Heading,
    Paragraph,
    Section,
    Table,
    fmt,
    pct,
)
from smcbayes.report.render import to_html, to_markdown

sys.path.insert(0, str(Path(__file__).resolve().parent))  # the shared HTML checker of these tests
from htmlcheck import PLACEHOLDER, external_references, parse_page


@pytest.fixture
def figure(tmp_path: Path) -> Path:
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(2, 2))
    ax.plot([0, 1], [0, 1], color="black", label="a-b measured")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("force (kN)")
    return save(fig, tmp_path / "figs" / "line")[0]


def sections(figure: Path) -> list[Section]:
    return [
        Section("one", "First <one>").add(
            Heading("sub & heading"),
            Paragraph("a < b and {braces} stay text", tone="warning"),
            Bullets(("x|y", "z")),
            Table(("name", "value"), (("a|b", "1.5"), ("<c>", "2")), "cap", (1,)),
            Figure(figure, "a figure"),
            Code("smcbayes report RUN"),
        ),
        Section("two", "Second").add(Paragraph("plain")),
    ]


def test_html_is_self_contained_and_escaped(figure: Path) -> None:
    page = to_html("Title", "sub", sections(figure))
    facts = parse_page(page)
    assert facts.sections == ["one", "two"]
    assert len(facts.img_src) == 1 and facts.img_src[0].startswith("data:image/png;base64,")
    assert external_references(facts) == [] and facts.stylesheets == [] and facts.scripts == 0
    assert "<one>" not in page and "&lt;one&gt;" in page and "&lt;c&gt;" in page
    assert 'class="warning"' in page and '<td class="num">1.5</td>' in page
    text = "".join(facts.text)
    assert "a < b and {braces} stay text" in text  # user text is escaped, not interpreted


def test_markdown_references_figures_relatively(figure: Path, tmp_path: Path) -> None:
    md = to_markdown("Title", "sub", sections(figure), tmp_path)
    assert "![a figure](figs/line.png)" in md and "figs/line.svg" in md
    assert "| a\\|b | 1.5 |" in md and "|---|---:|" in md
    assert "## First <one>" in md and "```\nsmcbayes report RUN\n```" in md
    assert "> **Warning:** a < b" in md


def test_placeholder_pattern_catches_template_leftovers() -> None:
    for leftover in ("{{ title }}", "{name}", "${x}", "value {best_loss}"):
        assert PLACEHOLDER.search(leftover), leftover
    for fine in ("body { color: red; }", "1.5e+04 kN", "{ }"):
        assert not PLACEHOLDER.search(fine), fine


def test_number_formatting() -> None:
    assert fmt(None) == "-" and fmt(float("nan")) == "-" and fmt(True) == "yes"
    assert fmt(12345.678) == "1.235e+04" and fmt(0.5) == "0.5" and fmt(3) == "3"
    assert pct(0.905) == "90 %" and pct(None) == "-"
