"""A trial's contact from its measured end state: the part, the hold's closing, the ram's travel."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from smcbayes.data.dataset import load_dataset
from smcbayes.data.loss import (
    LossSpec,
    contact_beyond_bound,
    contact_offsets_mm,
    end_state_offsets_mm,
    evaluate_loss,
    force_pair,
)
from smcbayes.errors import ConfigError, ContactOffsetWarning, DataError
from smcbayes.forward.result import SimulationResult

SPEED = 1.0  # mm/s: a delay of 0.2 s is a 0.2 mm offset
LIMIT = 300.0


def _write_rise(dh, tmp_path: Path, delay_s: float, top_kN: float = LIMIT, name: str = "c1") -> None:
    """A measured cubic rise reaching ``top_kN`` at 5 s + ``delay_s`` (first contact at 0)."""
    tm = np.linspace(0, 5 + delay_s, 400)
    fm = top_kN * (np.clip(tm - delay_s, 0, 5) / 5) ** 3
    body = "\n".join(f"{a:.17g},{b:.17g}" for a, b in zip(tm, fm, strict=True))
    dh.write_text(tmp_path / "force" / f"{name}.csv", "time_s,force_kN\n" + body + "\n")


def _config(dh, part: dict | None, hold: bool = False, cid: str = "c1", role: str = "train") -> dict:
    data = {"force": f"force/{cid}.csv"}
    if hold:
        dh.write_text(dh.tmp / "hold" / f"{cid}.csv", "time_s,displacement_mm\n1,-0.1\n400,-0.25\n")
        data["hold"] = f"hold/{cid}.csv"
    conf = dh.config(cid, data=data, role=role, speed_mm_s=SPEED, force_limit_kN=LIMIT)
    if part is not None:
        conf["part"] = part
    return conf


def _simulated(rows: int = 1, k_kN_mm: float | None = None) -> SimulationResult:
    """The undelayed rise, reaching the limit at 5 s after 5 mm of ram travel from an 8 mm
    stack; with ``k_kN_mm`` the frame deflects by F / k, so the gap closes that much less."""
    t = np.append(np.linspace(0, 5, 400), 505.0)
    f = np.append(LIMIT * (t[:-1] / 5) ** 3, LIMIT)
    d = SPEED * np.minimum(t, 5.0)
    gap = 8.0 - d + (f / k_kN_mm if k_kN_mm else 0.0)
    tile = lambda a: np.tile(a, (rows, 1))  # noqa: E731
    ones = np.ones((rows, t.size))
    phase = np.where(t <= 5.0, 1, 3).astype(np.int8)
    return SimulationResult("c1", tile(t), tile(gap), tile(d), tile(f), ones, ones, tile(phase),
                            np.full(rows, 5.0), ["ok"] * rows)


@pytest.fixture
def dhp(dh, tmp_path: Path):
    dh.tmp = tmp_path
    return dh


def test_the_part_gives_a_thickness_and_needs_a_density(dhp, tmp_path: Path) -> None:
    _write_rise(dhp, tmp_path, 0.0)
    proj = dhp.project(tmp_path, [_config(dhp, {"mass_g": 360.0})], defaults={"part": {"density_g_cm3": 1.5}})
    conf = proj.configuration[0]
    # 360 g over the 305 x 305 mm default cavity at 1.5 g/cm3
    assert conf.part.thickness(conf.mould) == pytest.approx(360.0 / (1.5 * 30.5 * 30.5) * 10.0)
    with pytest.raises(ConfigError, match="density_g_cm3"):
        dhp.project(tmp_path, [_config(dhp, {"mass_g": 360.0})])
    with pytest.raises(ConfigError, match="not both"):
        dhp.project(tmp_path, [_config(dhp, {"mass_g": 360.0, "thickness_mm": 2.0, "density_g_cm3": 1.5})])
    # a density alone measures nothing
    proj = dhp.project(tmp_path, [_config(dhp, {"density_g_cm3": 1.5})])
    assert load_dataset(proj)["c1"].end_stack_mm is None


def test_the_end_state_adds_part_hold_and_ram_travel(dhp, tmp_path: Path) -> None:
    _write_rise(dhp, tmp_path, 0.2)
    m = load_dataset(dhp.project(tmp_path, [_config(dhp, {"thickness_mm": 3.0}, hold=True)]))["c1"]
    # the limit is reached at 5.2 s
    assert m.end_stack_mm == pytest.approx(3.0 + 0.25 + SPEED * 5.2, abs=2e-3)
    assert any(s.startswith("end state: part 3.000 mm + 0.250 mm closed in the hold") for s in m.steps)


def test_a_curve_ending_just_short_of_the_limit_ends_there(dhp, tmp_path: Path) -> None:
    _write_rise(dhp, tmp_path, 0.0, top_kN=0.96 * LIMIT)
    m = load_dataset(dhp.project(tmp_path, [_config(dhp, {"thickness_mm": 3.0})]))["c1"]
    assert m.end_stack_mm == pytest.approx(3.0 + 5.0 * SPEED, abs=1e-6)
    assert any("no hold curve" in s for s in m.steps)
    _write_rise(dhp, tmp_path, 0.0, top_kN=0.8 * LIMIT)
    m = load_dataset(dhp.project(tmp_path, [_config(dhp, {"thickness_mm": 3.0})]))["c1"]
    assert m.end_stack_mm is None
    assert any("does not reach the force limit" in s for s in m.steps)


def test_the_end_state_offset_recovers_a_thicker_charge(dhp, tmp_path: Path) -> None:
    """Measured 0.2 s (0.2 mm) later than simulated, ending at the simulated gap: the
    end-state offset is 0.2 mm and the error vanishes; at the nominal contact it does not."""
    _write_rise(dhp, tmp_path, 0.2)
    # the part as thick as the simulated gap at the limit (3 mm), nothing closed in the hold
    ds = load_dataset(dhp.project(tmp_path, [_config(dhp, {"thickness_mm": 3.0})]))
    sim = _simulated(rows=2)
    spec = LossSpec(contact="end_state")
    np.testing.assert_allclose(end_state_offsets_mm(sim, ds["c1"]), 0.2, atol=2e-3)
    pair = force_pair(sim, ds["c1"], spec)
    np.testing.assert_allclose(pair.offset_mm, 0.2, atol=2e-3)
    assert np.all(evaluate_loss({"c1": sim}, ds, spec).total < 1.0)
    assert evaluate_loss({"c1": sim}, ds, LossSpec()).total[0] > 10.0
    # a compliant frame deflects by F / k at the limit: the charge stood that much lower
    soft = _simulated(k_kN_mm=1000.0)
    np.testing.assert_allclose(end_state_offsets_mm(soft, ds["c1"]), 0.2 - LIMIT / 1000.0, atol=2e-3)


def test_end_state_contact_needs_the_part_of_every_training_trial(dhp, tmp_path: Path) -> None:
    _write_rise(dhp, tmp_path, 0.2)
    _write_rise(dhp, tmp_path, 0.2, name="v1")
    bare = load_dataset(dhp.project(tmp_path, [_config(dhp, None)]))
    with pytest.raises(DataError, match="part.thickness_mm"):
        evaluate_loss({"c1": _simulated()}, bare, LossSpec(contact="end_state"))
    # a trial without its end state has no offset of its own (a new trial: predicted across
    # the training trials' offsets), a pressed one has
    ds = load_dataset(dhp.project(tmp_path, [_config(dhp, {"thickness_mm": 3.0}),
                                             _config(dhp, None, cid="v1", role="validation")]))
    offsets = contact_offsets_mm({"c1": _simulated(), "v1": _simulated()}, ds, LossSpec(contact="end_state"),
                                 ["c1", "v1"])
    assert list(offsets) == ["c1"] and offsets["c1"] == pytest.approx(0.2, abs=2e-3)
    # given an offset, the trial without one is compared at it
    total = evaluate_loss({"v1": _simulated()}, ds, LossSpec(contact="end_state"), ["v1"], {"v1": 0.2}).total
    assert total[0] < 1.0


def test_a_failed_row_or_a_gap_that_is_not_finite_has_no_offset(dhp, tmp_path: Path) -> None:
    _write_rise(dhp, tmp_path, 0.2)
    m = load_dataset(dhp.project(tmp_path, [_config(dhp, {"thickness_mm": 3.0})]))["c1"]
    sim = _simulated(rows=3)
    sim.gap_mm[1, 100:] = np.nan
    sim.status[2] = "failed: test"
    np.testing.assert_allclose(end_state_offsets_mm(sim, m), [0.2, 0.0, 0.0], atol=2e-3)


def test_a_width_alone_still_profiles_and_a_profile_needs_a_width() -> None:
    assert LossSpec().contact_mode == "nominal" and not LossSpec().per_trial_contact
    assert LossSpec(contact_offset_mm=0.3).contact_mode == "profile"
    # a copy given a width profiles too (model_copy does not validate)
    assert LossSpec().model_copy(update={"contact_offset_mm": 0.3}).contact_mode == "profile"
    assert LossSpec(contact="end_state").per_trial_contact
    with pytest.raises(ValueError, match="contact_offset_mm"):
        LossSpec(contact="profile")
    with pytest.raises(ValueError, match="remove it"):
        LossSpec(contact="nominal", contact_offset_mm=0.3)
    # with the end state, the width bounds the measured offset
    assert LossSpec(contact="end_state", contact_offset_mm=0.3).contact_mode == "end_state"


def test_a_bound_clips_the_end_state_offset_and_names_the_trials_beyond_it(dhp, tmp_path: Path) -> None:
    """The charge measured 0.2 mm above the simulated one and a frame that would put it
    0.1 mm below: within +-0.15 mm both are compared at the bound and named; the error the
    bound leaves is paid in the loss."""
    _write_rise(dhp, tmp_path, 0.2)
    ds = load_dataset(dhp.project(tmp_path, [_config(dhp, {"thickness_mm": 3.0})]))
    sims = {"c1": _simulated(), "soft": _simulated(k_kN_mm=1000.0)}
    bounded = LossSpec(contact="end_state", contact_offset_mm=0.15)
    np.testing.assert_allclose(end_state_offsets_mm(sims["c1"], ds["c1"], 0.15), 0.15)
    np.testing.assert_allclose(end_state_offsets_mm(sims["soft"], ds["c1"], 0.15), -0.1, atol=2e-3)
    beyond = contact_beyond_bound({"c1": sims["c1"]}, ds, bounded, ["c1"])
    assert beyond == pytest.approx({"c1": 0.2}, abs=2e-3)
    assert contact_beyond_bound({"c1": sims["soft"]}, ds, bounded, ["c1"]) == {}
    assert contact_beyond_bound({"c1": sims["c1"]}, ds, LossSpec(contact="end_state"), ["c1"]) == {}
    assert evaluate_loss({"c1": sims["c1"]}, ds, bounded).total[0] > \
        10 * evaluate_loss({"c1": sims["c1"]}, ds, LossSpec(contact="end_state")).total[0]
    text = ContactOffsetWarning.advice("c1", 0.2, 0.15)
    assert "+0.20 mm" in text and "+-0.15 mm" in text
