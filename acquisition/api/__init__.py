"""The Python API: what a researcher's capture script calls, and the only thing the CLI calls.

>>> from acquisition.api import capture, reduce
>>> capture("examples/rig-sim.toml", "examples/plan-quick.toml", "runs/s1",
...         material="lambert:albedo=0.5", seed=1)            # doctest: +SKIP
>>> reduce("runs/s1", "runs/s1/brdf.h5").table.count.sum()    # doctest: +SKIP

Every name is loaded on first use (PEP 562), so ``import acquisition.api`` and ``gonio --help``
stay fast: a command pays only for the modules it uses.

May import: ``acquisition``, ``calibration``, ``drivers`` (every room below it; never
``acquisition.cli``).
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

_EXPORTS: dict[str, tuple[str, ...]] = {
    "acquisition.api.sessions": (
        "Progress", "OnOpen", "CaptureResult", "plan_sweep",
        "predicted_step_s", "step_durations", "run_session", "capture", "resume",
        "ScriptedSession", "scripted_session", "reduce",
    ),
    "acquisition.api.library": ("reduce_many", "table_paths"),
    "acquisition.api.streaming": ("follow_session", "FollowResult", "StreamingError"),
    "acquisition.reduction.distributed": ("DistributedError",),
    "acquisition.api.demo": ("run_demo", "DemoResult"),
    "acquisition.api.analysis": ("open_table", "fit", "median_relative_uncertainty", "check",
                                 "CheckReport", "compare", "report", "ReportResult",
                                 "REPORT_MODELS"),
    "acquisition.analysis.compare": ("Comparison",),
    "acquisition.analysis.fit": ("FitResult",),
    "acquisition.analysis.models": ("MODEL_NAMES", "make_model"),
    "acquisition.simworld.materials": ("DEFAULT_MATERIAL",),
    "acquisition.geometry.kinematics": ("Pose",),
    "acquisition.planning.planner": ("Planner", "Sweep", "Rejection", "Reason"),
    "acquisition.session.folder": ("SessionFolder",),
    "acquisition.session.status": ("SessionStatus", "session_status"),
    "acquisition.session.verify": ("VerifyReport", "verify_session"),
    "acquisition.session.journal": ("StepRecord",),
    "acquisition.session.observers": (
        "Observer", "LogObserver", "ProgressObserver", "CallbackObserver",
    ),
    "acquisition.session.interrupts": ("sigint_stops_motion", "FIRST_MESSAGE", "LIGHTS_MESSAGE"),
    "acquisition.devices.rig": ("OperatorPrompt",),
    "acquisition.devices.console": (
        "Console", "AxisStatus", "ScanResult", "ALL_IDS", "open_console", "scan_port",
        "scan_rig", "format_status", "format_scan", "format_pose", "format_route",
        "pose_fields", "home_joints", "require_moving_axes",
    ),
    "acquisition.calibrate.radiometric": ("KINDS", "CalibrationRun", "calibrate"),
    "acquisition.calibrate.geometry": ("GeometryRun", "calibrate_geometry"),
    "acquisition.reduction.point": ("Reduction", "reduce_session"),
    "acquisition.reduction": ("CHECKPOINT_EVERY",),
    "acquisition.reduction.checkpoint": ("checkpoint_path",),
    "acquisition.reduction.image": ("ImageReducer",),
    "acquisition.tables.partial": ("ReductionPartial", "TablePartial", "merge_all", "save_partial",
                                   "load_partial"),
    "acquisition.reduction.live": ("LiveReduction",),
    "acquisition.tables": ("IsotropicTable", "MerlTable"),
    "acquisition.formats.merl": ("read_merl", "write_merl"),
    "acquisition.formats.export": ("ExportFormat", "export_table", "load_table", "table_info"),
    "acquisition.lightstage.reduce": ("is_lightstage_session",),
    "acquisition.lightstage.capture": (
        "FIELD_DIR", "LightStageResult", "capture_lightstage", "resume_lightstage", "plan_lightstage",
        "session_sequences",
    ),
    "acquisition.lightstage.field": ("write_field",),
    "acquisition.lightstage.relight": ("relight_files",),
    "acquisition.lightstage.sequences": ("SEQUENCES", "TimeEstimate"),
    "acquisition.analysis.plots": ("plot_slices", "plot_sweep"),
    "acquisition.simworld.serve": ("serve_servos", "serve_rig", "serve_dmx"),
    "calibration.raw": ("inspect_raw", "format_inspection"),
    "drivers.dynamixel.bus": ("COMMON_BAUD_RATES",),
    "drivers.errors": ("GonioError", "ConfigError", "SessionError", "StorageError",
                       "OutputRefused"),
    "drivers.storage": ("os_error_line",),
}
_WHERE = {name: module for module, names in _EXPORTS.items() for name in names}

__all__ = sorted(_WHERE)


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        raise AttributeError(f"module 'acquisition.api' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


if TYPE_CHECKING:  # what type checkers and IDEs see
    from acquisition.analysis.compare import Comparison
    from acquisition.analysis.fit import FitResult
    from acquisition.analysis.models import MODEL_NAMES, make_model
    from acquisition.analysis.plots import plot_slices, plot_sweep
    from acquisition.api.analysis import (
        REPORT_MODELS,
        CheckReport,
        ReportResult,
        check,
        compare,
        fit,
        median_relative_uncertainty,
        open_table,
        report,
    )
    from acquisition.api.demo import DemoResult, run_demo
    from acquisition.api.library import reduce_many, table_paths
    from acquisition.api.sessions import (
        CaptureResult,
        OnOpen,
        Progress,
        ScriptedSession,
        capture,
        plan_sweep,
        predicted_step_s,
        reduce,
        resume,
        run_session,
        scripted_session,
        step_durations,
    )
    from acquisition.api.streaming import FollowResult, StreamingError, follow_session
    from acquisition.calibrate.geometry import GeometryRun, calibrate_geometry
    from acquisition.calibrate.radiometric import KINDS, CalibrationRun, calibrate
    from acquisition.devices.console import (
        ALL_IDS,
        AxisStatus,
        Console,
        ScanResult,
        format_pose,
        format_route,
        format_scan,
        format_status,
        home_joints,
        open_console,
        pose_fields,
        require_moving_axes,
        scan_port,
        scan_rig,
    )
    from acquisition.devices.rig import OperatorPrompt
    from acquisition.formats.export import ExportFormat, export_table, load_table, table_info
    from acquisition.formats.merl import read_merl, write_merl
    from acquisition.geometry.kinematics import Pose
    from acquisition.lightstage.capture import (
        FIELD_DIR,
        LightStageResult,
        capture_lightstage,
        plan_lightstage,
        resume_lightstage,
        session_sequences,
    )
    from acquisition.lightstage.field import write_field
    from acquisition.lightstage.reduce import is_lightstage_session
    from acquisition.lightstage.relight import relight_files
    from acquisition.lightstage.sequences import SEQUENCES, TimeEstimate
    from acquisition.planning.planner import Planner, Reason, Rejection, Sweep
    from acquisition.reduction import CHECKPOINT_EVERY
    from acquisition.reduction.checkpoint import checkpoint_path
    from acquisition.reduction.distributed import DistributedError
    from acquisition.reduction.image import ImageReducer
    from acquisition.reduction.live import LiveReduction
    from acquisition.reduction.point import Reduction, reduce_session
    from acquisition.session.folder import SessionFolder
    from acquisition.session.interrupts import FIRST_MESSAGE, LIGHTS_MESSAGE, sigint_stops_motion
    from acquisition.session.journal import StepRecord
    from acquisition.session.observers import (
        CallbackObserver,
        LogObserver,
        Observer,
        ProgressObserver,
    )
    from acquisition.session.status import SessionStatus, session_status
    from acquisition.session.verify import VerifyReport, verify_session
    from acquisition.simworld.materials import DEFAULT_MATERIAL
    from acquisition.simworld.serve import serve_dmx, serve_rig, serve_servos
    from acquisition.tables import IsotropicTable, MerlTable
    from acquisition.tables.partial import (
        ReductionPartial,
        TablePartial,
        load_partial,
        merge_all,
        save_partial,
    )
    from calibration.raw import format_inspection, inspect_raw
    from drivers.dynamixel.bus import COMMON_BAUD_RATES
    from drivers.errors import ConfigError, GonioError, OutputRefused, SessionError, StorageError
    from drivers.storage import os_error_line
