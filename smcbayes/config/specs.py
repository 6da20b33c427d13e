"""Typed options of the pre-processing and of the loss (``[preprocess]`` and ``[loss]``).

Part of the configuration layer: no imports from the rest of the package.
"""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

ClipMode = Literal["none", "flow_stop", "force_limit"]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class PreprocessSpec(_Strict):
    """Optional pre-processing of measured curves; every step applied is recorded.

    Attributes:
        trim_idle: drop idle press states: samples before the last one below the contact
            threshold that precedes the force rise, and samples after the press opened
            (force back below the threshold after its peak).
        zero_at_contact: put t = 0 where the force first reaches ``contact_threshold_kN``
            (linear interpolation between samples); earlier samples are dropped.
        contact_threshold_kN: force that marks first contact (kN).
        smooth_window_s: Savitzky-Golay window (s); None switches smoothing off.
        smooth_order: Savitzky-Golay polynomial order.
        resample_dt_s: resample every curve to a uniform grid of this spacing (s).
        clip: cut the measured closing curve at the incompressible flow-stop time
            (thesis eq. 4.1) or at its first crossing of the force limit.
    """

    trim_idle: bool = False
    zero_at_contact: bool = False
    contact_threshold_kN: float = Field(2.0, gt=0)
    smooth_window_s: float | None = Field(None, gt=0)
    smooth_order: int = Field(3, ge=1, le=6)
    resample_dt_s: float | None = Field(None, gt=0)
    clip: ClipMode = "none"


class LossSpec(_Strict):
    """Options of the loss (thesis eq. 3.5-3.7).

    Attributes:
        w_force: weight w_F of the force MSE (kN^2).
        w_displacement: weight w_D of the hold-displacement MSE (mm^2).
        grid_points: points N of the common time grid per configuration.
        clip: ``none``: force compared over [0, max(t_switch_sim, t_end_meas)];
            ``flow_stop``: over [0, t_flow_stop] (the thesis's clipped loss);
            ``force_limit``: both curves cut where they first reach the force limit and
            their values capped at the limit.
        contact_offset_mm: how far (mm of ram travel) a trial's contact may lie from the
            nominal stack height (hand-cut charges differ from trial to trial).  With
            ``contact = "profile"`` each configuration is compared at its best contact
            offset within +- this (a nuisance parameter per trial, profiled out of the
            loss); given alone (above 0) it means the profile.  With ``contact =
            "end_state"`` it bounds the measured offset (0: unbounded): a model whose end
            of closing would put the charge further from its nominal height (a ram that
            lags, a frame that yields, far from the press's) is compared at the bound and
            pays for the rest in the loss, instead of being aligned with every trial by an
            offset no charge could have.  0 (default); at most 2 mm (a quarter of a typical
            8 mm stack: beyond it the first-order delay no longer stands for a thicker
            charge; an unbounded end-state offset may exceed it).
        contact: where each training trial's contact lies.  ``nominal``: at the stack
            height; ``profile``: the best offset within +- ``contact_offset_mm``;
            ``end_state``: the offset that the trial's
            measured end state implies (the part's thickness, the hold's closing and the
            ram's travel to the force limit; see
            :func:`smcbayes.data.loss.end_state_offsets_mm`), so the offset is measured,
            not fitted, and a model that ends the closing at the wrong gap pays for it.
            A configuration outside the loss is predicted across the training trials'
            offsets in either case.  Not given: ``profile`` for a width above 0, else
            ``nominal`` (:attr:`contact_mode`).
    """

    w_force: float = Field(1.0, ge=0)
    w_displacement: float = Field(0.0, ge=0)
    grid_points: int = Field(400, ge=2, le=100000)
    clip: ClipMode = "none"
    contact_offset_mm: float = Field(0.0, ge=0, le=2.0)
    contact: Literal["nominal", "profile", "end_state"] | None = None

    @model_validator(mode="after")
    def _width_for_a_moving_contact(self) -> LossSpec:
        if self.contact == "profile" and self.contact_offset_mm <= 0:
            raise ValueError('contact = "profile" needs contact_offset_mm > 0 (the range searched)')
        if self.contact == "nominal" and self.contact_offset_mm > 0:
            raise ValueError('contact_offset_mm is the range of a contact that moves (profile, end_state); '
                             'with contact = "nominal" remove it (or set it to 0)')
        return self

    @property
    def contact_mode(self) -> Literal["nominal", "profile", "end_state"]:
        """``contact``, or where it is not given ``profile`` for a width above 0 (what a
        width alone has always meant) and else ``nominal``."""
        if self.contact is not None:
            return self.contact
        return "profile" if self.contact_offset_mm > 0 else "nominal"

    @property
    def per_trial_contact(self) -> bool:
        """Whether each trial has a contact offset of its own (profiled or measured)."""
        return self.contact_mode != "nominal"
