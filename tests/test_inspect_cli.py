"""``gonio inspect``: the loader's view of a RAW file, as text or one JSON object."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from acquisition.cli import main
from simulators.dng import write_dng


def _dng(path: Path, **kwargs) -> Path:
    mosaic = np.full((32, 48), 600, dtype=np.uint16)
    return write_dng(path, mosaic, cfa_pattern="GBRG", black_level=[[64, 66], [68, 70]],
                     white_level=4095, **kwargs)


def test_inspect_json_prints_one_object(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _dng(tmp_path / "a.dng", exposure_s=0.02, iso=200, f_number=5.6)
    assert main(["inspect", str(path), "--json"]) == 0
    out = capsys.readouterr().out
    assert out.count("\n") == 1
    info = json.loads(out)
    assert info == {"pattern": "GBRG", "black": {"R": 68, "G": 67, "B": 66}, "white": 4095,
                    "width": 48, "height": 32, "exposure_s": 0.02, "iso": 200, "f_number": 5.6}


def test_inspect_text_and_unknown_metadata(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _dng(tmp_path / "b.dng")
    assert main(["inspect", str(path)]) == 0
    out = capsys.readouterr().out
    assert "GBRG" in out and "48 × 32" in out and "exposure   unknown" in out
    assert main(["inspect", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["exposure_s"] is None and info["iso"] is None and info["f_number"] is None


def test_inspect_errors_are_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["inspect", str(tmp_path / "absent.dng")]) != 0
    err = capsys.readouterr().err
    assert err.startswith("gonio: error:") and err.count("\n") == 1 and "absent.dng" in err


def test_inspect_refuses_the_film_scanner_file(external_data: Path, capsys) -> None:
    path = external_data / "raw" / "Nikon_uncompressed.nef"
    if not path.exists():
        pytest.skip(f"{path} absent")
    assert main(["inspect", str(path), "--json"]) != 0
    assert "not a Bayer" in capsys.readouterr().err
