"""Dynamixel X-series servos over ``dynamixel_sdk`` (Protocol 2.0).

:class:`ServoBus` talks to one port (retries, typed errors), :class:`Axis` maps degrees to ticks
within soft limits, :class:`MotionController` runs guarded, read-back-confirmed multi-axis moves.
"""

from drivers.dynamixel.axis import Axis
from drivers.dynamixel.bus import (
    COMMON_BAUD_RATES,
    SDK_BAUD_RATES,
    Addr,
    MotionSample,
    ServoBus,
    ServoLinkStats,
    ServoStatus,
)
from drivers.dynamixel.codes import (
    ElectricalShockError,
    EncoderError,
    InputVoltageError,
    MotionTimeoutError,
    OverheatingError,
    OverloadError,
    PartialMoveError,
    ServoCommandError,
    ServoHardwareError,
    ServoSilentError,
    TorqueOffError,
)
from drivers.dynamixel.latency import latency_timer_ms, latency_warning
from drivers.dynamixel.motion import MotionController

__all__ = [
    "COMMON_BAUD_RATES", "SDK_BAUD_RATES", "Addr", "Axis", "ElectricalShockError",
    "EncoderError", "InputVoltageError", "MotionController", "MotionSample",
    "MotionTimeoutError", "OverheatingError", "OverloadError", "PartialMoveError", "ServoBus",
    "ServoCommandError", "ServoHardwareError", "ServoLinkStats", "ServoSilentError", "ServoStatus",
    "TorqueOffError", "latency_timer_ms", "latency_warning",
]
