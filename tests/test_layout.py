"""Charge layouts: union area, exact cell coverage, mirror symmetry, the square-charge factor."""

from __future__ import annotations

import numpy as np
import pytest

from smcbayes.forward.layout import (
    coverage,
    square_charge_factor,
    square_charge_tables,
    symmetric,
    union_area,
)


def raster_area(rects: list[tuple[float, float, float, float]], h: float) -> float:
    """Union area by counting cell centres of a raster of step h (exact when every edge lies
    on the raster's faces)."""
    c = np.arange(-1.0 + h / 2, 1.0, h)
    x, y = np.meshgrid(c, c, indexing="ij")
    inside = np.zeros_like(x, dtype=bool)
    for cx, cy, length, width in rects:
        inside |= (np.abs(x - cx) < length / 2) & (np.abs(y - cy) < width / 2)
    return float(inside.sum() * h * h)


def test_union_area_of_hand_computed_layouts() -> None:
    assert union_area([(0.0, 0.0, 0.2, 0.1)]) == pytest.approx(0.02)
    # disjoint: the sum
    assert union_area([(-0.3, 0.0, 0.2, 0.1), (0.3, 0.1, 0.1, 0.1)]) == pytest.approx(0.03)
    # two 0.2 x 0.2 squares overlapping in a 0.1 x 0.2 strip: 0.04 + 0.04 - 0.02
    assert union_area([(0.0, 0.0, 0.2, 0.2), (0.1, 0.0, 0.2, 0.2)]) == pytest.approx(0.06)
    # a cross: 0.3 x 0.1 and 0.1 x 0.3 sharing the 0.1 x 0.1 centre
    assert union_area([(0.0, 0.0, 0.3, 0.1), (0.0, 0.0, 0.1, 0.3)]) == pytest.approx(0.05)
    # nested and duplicated pieces add nothing
    assert union_area([(0.0, 0.0, 0.4, 0.4), (0.05, -0.05, 0.1, 0.1), (0.0, 0.0, 0.4, 0.4)]) \
        == pytest.approx(0.16)


def test_union_area_of_random_overlapping_layouts_equals_a_raster_count() -> None:
    rng = np.random.default_rng(0)
    for _ in range(20):
        k = int(rng.integers(1, 6))
        # edges on a 0.02 grid: centres on 0.01 multiples with even-hundredths sides
        cx, cy = rng.integers(-30, 31, (2, k)) * 0.01
        length, width = rng.integers(1, 25, (2, k)) * 0.02
        rects = list(zip(cx, cy, length, width, strict=True))
        assert union_area(rects) == pytest.approx(raster_area(rects, 0.01), rel=1e-9)


def test_coverage_sums_to_the_union_area_and_is_exact_per_cell() -> None:
    rects = [(0.0, 0.0, 0.2, 0.2), (0.1, 0.05, 0.2, 0.1)]
    faces = np.linspace(-0.3, 0.3, 13)  # 0.05 m cells
    cover = coverage(rects, faces, faces)
    assert cover.shape == (12, 12)
    assert cover.sum() == pytest.approx(union_area(rects))
    assert np.all(cover >= 0) and np.all(cover <= 0.05**2 * (1 + 1e-12))
    # a cell inside the first square is full, one outside everything empty
    assert cover[5, 5] == pytest.approx(0.0025) and cover[0, 0] == 0.0
    # a grid that cuts the charge: only the part inside counts
    off = coverage([(0.0, 0.0, 0.2, 0.2)], np.linspace(0.03, 0.33, 7), np.linspace(-0.3, 0.3, 13))
    assert off.sum() == pytest.approx(0.07 * 0.2)
    # a cell partly covered: 0.2 x 0.2 square from -0.1 to 0.1 on cells of 0.06
    part = coverage([(0.0, 0.0, 0.2, 0.2)], np.array([0.08, 0.14]), np.array([0.08, 0.14]))
    assert part[0, 0] == pytest.approx(0.02 * 0.02)


def test_symmetry_is_detected_per_axis() -> None:
    faces = np.linspace(-0.15, 0.15, 13)
    centred = coverage([(0.0, 0.0, 0.12, 0.08)], faces, faces)
    assert symmetric(centred, 0) and symmetric(centred, 1)
    shifted_x = coverage([(0.03, 0.0, 0.12, 0.08)], faces, faces)
    assert not symmetric(shifted_x, 0) and symmetric(shifted_x, 1)
    pair = coverage([(-0.05, 0.02, 0.04, 0.04), (0.05, 0.02, 0.04, 0.04)], faces, faces)
    assert symmetric(pair, 0) and not symmetric(pair, 1)


def test_square_charge_factor_limits_of_the_table() -> None:
    """Start and end of the filling at 60 % and 80 % coverage are the table's end values."""
    assert float(square_charge_factor(0.6, 0.6)) == pytest.approx(0.8876)
    assert float(square_charge_factor(1.0, 0.6)) == pytest.approx(3.2945)
    assert float(square_charge_factor(0.8, 0.8)) == pytest.approx(0.8899)
    assert float(square_charge_factor(1.0, 0.8)) == pytest.approx(3.7733)
    # before the start and beyond the end the progress is clipped
    assert float(square_charge_factor(0.5, 0.6)) == pytest.approx(0.8876)
    assert float(square_charge_factor(1.2, 0.6)) == pytest.approx(3.2945)


def test_square_charge_factor_interpolates_geometrically_in_coverage_and_holds_outside() -> None:
    fill_of = lambda fill0, u: fill0 + u * (1.0 - fill0)  # noqa: E731
    for u in (0.0, 0.3, 0.7, 0.95, 0.999):
        low = float(square_charge_factor(fill_of(0.6, u), 0.6))
        high = float(square_charge_factor(fill_of(0.8, u), 0.8))
        mid = float(square_charge_factor(fill_of(0.7, u), 0.7))
        assert mid == pytest.approx(np.sqrt(low * high), rel=1e-12)
        assert float(square_charge_factor(fill_of(0.4, u), 0.4)) == pytest.approx(low, rel=1e-12)
        assert float(square_charge_factor(fill_of(0.9, u), 0.9)) == pytest.approx(high, rel=1e-12)


def test_square_charge_factor_rises_with_the_filling_and_keeps_the_shape() -> None:
    fill = np.linspace(0.6, 1.0, 400).reshape(20, 20, 1)
    f = square_charge_factor(fill, 0.6)
    assert f.shape == fill.shape
    assert np.all(np.diff(f.ravel()) >= 0)
    assert f.ravel()[-1] / f.ravel()[0] > 3.0  # the 2-D force rises far more towards the end


def test_square_charge_tables_reproduce_the_factor() -> None:
    x, low, high, w = square_charge_tables(0.75)
    assert w == pytest.approx(0.75) and x[0] == 0.0 and np.all(np.diff(x) > 0)
    fill = np.array([0.75, 0.8, 0.9, 0.99, 1.0])
    u = (fill - 0.75) / 0.25
    xq = -np.log10(np.maximum(1.0 - u, 1e-12))
    expect = np.interp(xq, x, low) ** (1 - w) * np.interp(xq, x, high) ** w
    np.testing.assert_allclose(square_charge_factor(fill, 0.75), expect, rtol=1e-12)
