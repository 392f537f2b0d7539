"""Frames are re-opened before they get their final name: a DNG cut short (by the camera, the
transfer or the disk) is one line naming the frame, nothing is left under its name, and
`gonio resume` retakes it. The check parses the TIFF structure only (no pixel decoded): well
under a millisecond per frame."""

from __future__ import annotations

import re
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import EXAMPLES, TINY_MATERIAL, TINY_PLAN_ARGS, grid_plan_text
from disks import bad_leftovers, one_error_line

from acquisition.cli import main
from acquisition.session.frames import FrameDamaged, check_raw_frame
from acquisition.session.journal import Journal
from drivers.errors import StorageError
from drivers.storage import atomic_output
from simulators.camera import SimCamera
from simulators.dng import write_dng

RIG = EXAMPLES / "rig-sim.toml"


@pytest.fixture(scope="module")
def dng(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A DNG of the simulated camera's size and layout (EXIF IFD last, after the pixels)."""
    path = tmp_path_factory.mktemp("dng") / "frame.dng"
    mosaic = np.random.default_rng(0).integers(0, 4000, (64, 96)).astype(np.uint16)
    write_dng(path, mosaic, exposure_s=0.01, iso=100, f_number=8.0)
    return path


def test_a_whole_dng_passes_in_well_under_a_millisecond(dng: Path) -> None:
    check_raw_frame(dng)
    best = min(_timed(dng) for _ in range(50))
    assert best < 1e-3, f"the frame check took {best * 1e3:.2f} ms"


def _timed(path: Path) -> float:
    t = time.perf_counter()
    check_raw_frame(path)
    return time.perf_counter() - t


@pytest.mark.parametrize("keep", [8 + 100, 1 / 3, -1])
def test_a_cut_dng_is_damaged(keep: float, dng: Path, tmp_path: Path) -> None:
    """Cut inside IFD0, inside the pixels, or by one byte (the EXIF IFD, written last)."""
    data = dng.read_bytes()
    n = int(keep) if keep >= 1 else (len(data) - 1 if keep == -1 else int(len(data) * keep))
    cut = tmp_path / "cut.dng"
    cut.write_bytes(data[:n])
    with pytest.raises(FrameDamaged, match="truncated|does not parse"):
        check_raw_frame(cut)


def test_formats_that_are_not_tiff_are_left_to_the_size_check(tmp_path: Path) -> None:
    other = tmp_path / "frame.cr3"
    other.write_bytes(b"\0\0\0\x18ftypcrx " + b"\0" * 64)
    check_raw_frame(other)


def test_the_writer_refuses_a_cut_dng_under_its_final_name(dng: Path, tmp_path: Path) -> None:
    final = tmp_path / "step-000001.dng"
    with pytest.raises(StorageError) as err, atomic_output(final, what="frame",
                                                           verify=check_raw_frame) as tmp:
        tmp.write_bytes(dng.read_bytes()[:-40])
    assert str(final) in str(err.value) and "truncated" in str(err.value)
    assert list(tmp_path.iterdir()) == []


@pytest.fixture
def plan(tmp_path: Path) -> Path:
    p = tmp_path / "plan.toml"
    p.write_text(grid_plan_text(*TINY_PLAN_ARGS))
    return p


@pytest.mark.parametrize("retries", [0, 4], ids=["no-retake", "clip-retakes"])
def test_a_camera_that_writes_a_cut_dng_stops_the_run_in_one_line(
    retries: int, plan: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
    capsys: pytest.CaptureFixture[str],
) -> None:
    """With retakes of clipped frames the frame is checked before its pixels are decoded; the
    line names the frame's final name, not a temporary one."""
    rig = tmp_path / "rig.toml"
    rig.write_text(RIG.read_text().replace("[camera]\n", f"[camera]\nmax_exposure_retries = {retries}\n", 1))
    real = SimCamera.capture
    calls: list[Path] = []

    def cutting(self: SimCamera, path: str, *args: object, **kw: object) -> object:
        info = real(self, path, *args, **kw)  # type: ignore[arg-type]
        calls.append(Path(path))
        if len(calls) == 3:
            data = Path(path).read_bytes()
            Path(path).write_bytes(data[: len(data) // 2])
        return info

    monkeypatch.setattr(SimCamera, "capture", cutting)
    out = tmp_path / "s"
    capsys.readouterr()
    code = main(["capture", "--rig", str(rig), "--plan", str(plan), "-o", str(out),
                 "--material", TINY_MATERIAL])
    line = one_error_line(capsys.readouterr().err)
    assert code != 0
    frames = sorted(p.name for p in (out / "frames").iterdir())
    assert len(frames) == 2 and bad_leftovers(out) == []
    name = re.fullmatch(r"\.(step-(\d+))\.\w+\.partial\.dng", calls[2].name)
    assert name is not None, calls[2]
    final = out / "frames" / f"{name[1]}.dng"
    assert not final.exists()
    assert f"cannot write frame {final}:" in line and "truncated" in line, line
    assert f"gonio resume {out}" in line and ".partial" not in line, line
    with Journal(out / "journal.sqlite", readonly=True) as journal:
        rec = journal.record(int(name[2]))
    assert rec is not None and rec.status != "done"

    monkeypatch.setattr(SimCamera, "capture", real)
    assert main(["resume", str(out)]) == 0
    assert main(["verify", str(out)]) == 0
