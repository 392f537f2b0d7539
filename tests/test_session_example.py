"""examples/scripted_session.py runs on the simulated rig and finds the specular peak."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np

from acquisition.api.truth import relative_errors, truth_table
from acquisition.session.folder import JOURNAL_FILE
from acquisition.session.journal import Journal
from acquisition.tables import IsotropicTable

EXAMPLE = Path(__file__).resolve().parent.parent / "examples" / "scripted_session.py"
MATERIAL = "ggx:albedo=0.2,alpha=0.15,f0=0.04"


def _load_example():  # noqa: ANN202
    spec = importlib.util.spec_from_file_location("scripted_session", EXAMPLE)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _argmax_centre(table: IsotropicTable) -> tuple[float, float, float]:
    g = np.where(table.count > 0, table.mean[..., 1], -np.inf)
    i, j, k = np.unravel_index(int(np.argmax(g)), g.shape)
    ti, tr, dp = table.centers()
    return float(ti[i]), float(tr[j]), float(dp[k])


def test_coarse_then_fine_finds_the_true_peak_and_resumes_as_a_no_op(tmp_path: Path) -> None:
    example = _load_example()
    peaks = example.run(tmp_path, MATERIAL, seed=4)
    assert peaks["coarse"].as_tuple() == (45.0, 45.0, 180.0)  # the mirror direction
    fine_truth = truth_table(tmp_path / "fine")
    assert peaks["fine"].as_tuple() == _argmax_centre(fine_truth)
    fine = IsotropicTable.load_h5(tmp_path / "fine" / "brdf.h5")
    assert int((fine.count > 0).sum()) >= 20
    assert np.all(fine.count[fine.count > 0] == 2)  # the 2-frame bracket
    assert np.median(relative_errors(fine, fine_truth)) < 0.03

    # Rerunning the script with --resume on finished sessions takes nothing again.
    frames = {p: p.stat().st_mtime_ns for p in tmp_path.glob("*/frames/*.dng")}
    again = example.run(tmp_path, MATERIAL, seed=4, resume=True)
    assert again["fine"] == peaks["fine"]
    assert {p: p.stat().st_mtime_ns for p in tmp_path.glob("*/frames/*.dng")} == frames
    with Journal(tmp_path / "fine" / JOURNAL_FILE) as j:
        assert all(r.attempts == 1 for r in j.steps())
