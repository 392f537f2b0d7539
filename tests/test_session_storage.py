"""A full disk stops a capture cleanly and leaves a resumable session; calibration is copied."""

from __future__ import annotations

import errno
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from conftest import TINY_PLAN_ARGS, grid_plan_text

import simulators.camera
from acquisition import api
from acquisition.cli import main
from acquisition.session.folder import JOURNAL_FILE, SessionFolder
from acquisition.session.journal import Journal
from drivers.errors import SessionError, StorageError

PLAN = grid_plan_text(*TINY_PLAN_ARGS, name="tiny")
MATERIAL = "lambert:albedo=0.4"


@pytest.fixture
def plan_path(tmp_path: Path) -> Path:
    p = tmp_path / "plan.toml"
    p.write_text(PLAN)
    return p


def _fill_disk_after(monkeypatch: pytest.MonkeyPatch, frames_ok: int) -> None:
    """The camera's DNG writer gets ENOSPC half way through frame number ``frames_ok + 1``."""
    real = simulators.camera.write_dng
    calls = {"n": 0}

    def write_dng(path: Any, *args: Any, **kwargs: Any) -> None:
        calls["n"] += 1
        if calls["n"] > frames_ok:
            Path(path).write_bytes(b"II*\0" + b"\0" * 100)  # what fitted on the disk
            raise OSError(errno.ENOSPC, "No space left on device", str(path))
        real(path, *args, **kwargs)

    monkeypatch.setattr(simulators.camera, "write_dng", write_dng)


def test_disk_full_stops_cleanly_and_resumes(
    rig_sim_path: Path, plan_path: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    whole = tmp_path / "whole"
    api.capture(rig_sim_path, plan_path, whole, material=MATERIAL, seed=5)

    out = tmp_path / "full"
    _fill_disk_after(monkeypatch, 3)
    code = main(["capture", "--rig", str(rig_sim_path), "--plan", str(plan_path), "--out",
                 str(out), "--material", MATERIAL, "--seed", "5"])
    err = capsys.readouterr().err
    assert code == StorageError("x").exit_code != 0
    message = err.strip().splitlines()[-1]
    assert message.startswith(
        f"gonio: error: cannot write frame {out / 'frames' / 'step-000003.dng'}: disk full")
    assert f"gonio resume {out}" in message and "Traceback" not in err
    assert sorted(p.name for p in (out / "frames").iterdir()) == [
        f"step-{i:06d}.dng" for i in range(3)
    ]  # the half-written frame is gone
    with Journal(out / JOURNAL_FILE) as j:
        recs = list(j.steps())
        assert j.counts() == {"done": 3, "started": 1, "planned": len(recs) - 4}
        assert any(level == "error" and "disk full" in msg for _, level, _, msg in j.events())

    monkeypatch.undo()  # space freed
    api.resume(out)
    a, b = api.reduce(whole).table, api.reduce(out).table
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_array_equal(a.mean, b.mean)


def test_calibration_is_copied_into_the_session(
    rig_sim_path: Path, plan_path: Path, tmp_path: Path
) -> None:
    cal = tmp_path / "cal"
    cal.mkdir()
    (cal / "flat.npz").write_bytes(b"flat field")
    (cal / "dark.json").write_text(json.dumps({"black_dn": 512}))
    out = tmp_path / "s"
    api.capture(rig_sim_path, plan_path, out, material=MATERIAL, calibration=cal)
    folder = SessionFolder(out)
    assert folder.calibration == out / "calibration"
    assert (out / "calibration" / "flat.npz").read_bytes() == b"flat field"

    one = tmp_path / "cal.json"
    one.write_text("{}")

    assert main(["capture", "--rig", str(rig_sim_path), "--plan", str(plan_path), "--out",
                 str(tmp_path / "s2"), "--material", MATERIAL, "--calibration", str(one)]) == 0
    assert SessionFolder(tmp_path / "s2").calibration == tmp_path / "s2" / "calibration" / "cal.json"


def test_missing_calibration_creates_nothing(rig_sim_path: Path, plan_path: Path,
                                             tmp_path: Path) -> None:
    with pytest.raises(SessionError, match="calibration .* does not exist"):
        api.capture(rig_sim_path, plan_path, tmp_path / "s", material=MATERIAL,
                    calibration=tmp_path / "nope")
    assert not (tmp_path / "s").exists()
