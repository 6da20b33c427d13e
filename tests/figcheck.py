"""Checks of written figure files shared by the figure tests: a PNG and its SVG twin."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path


def assert_png_and_svg(paths: list[Path], stem: Path) -> None:
    """``paths`` are ``stem.png`` and ``stem.svg``, both written and well-formed."""
    assert paths == [stem.with_suffix(".png"), stem.with_suffix(".svg")]
    png, svg = paths
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 1000
    root = ET.parse(svg).getroot()
    assert root.tag.endswith("svg")
