"""HDR sessions: the journal notes and meta keys of brackets, and the noise model that weighs
their frames."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from acquisition.config.rig import RigConfig
from acquisition.config.sensor import nominal_noise_model
from calibration.linearize import NoiseModel
from drivers.errors import (
    SessionError,
)

if TYPE_CHECKING:
    pass


HDR_SWEEP_META = "hdr_sweep"
"""Journal meta of an HDR capture session: its planned poses [θi, θr, Δφ, joints] (deg)."""


HDR_DONE_META = "hdr_done:"
"""Journal meta key prefix: ``hdr_done:<first step>`` → frames of a completed bracket."""


HDR_NOTE = "hdr="
"""Journal note prefix of an HDR bracket's frames: ``hdr=<first step>:<index>``."""


def hdr_group(note: str | None) -> int | None:
    """The first step of the HDR bracket a journal row belongs to (None: not an HDR frame)."""
    if not note or not note.startswith(HDR_NOTE):
        return None
    return int(note[len(HDR_NOTE):].split(":", 1)[0])


def camera_noise_model(rig: RigConfig, iso: float, bundle: Any = None) -> NoiseModel:
    """The noise model for HDR weights at ``iso``: the calibration bundle's, else (simulated
    camera only) the nominal one of the rig's ``[camera.sensor]``.

    Raises
    ------
    SessionError
        A real camera without a measured noise model.
    """
    noise = bundle.noise_for(iso) if bundle is not None else None
    if noise is not None:
        return noise
    if rig.camera.driver != "simulated":
        raise SessionError(
            f"HDR on rig '{rig.name}' needs a noise model at ISO {iso:g}: run "
            "`gonio calibrate noise` and give the bundle with --calibration"
        )
    return nominal_noise_model(rig, iso)
