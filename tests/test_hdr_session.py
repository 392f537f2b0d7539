"""HDR captures: auto-exposure brackets per pose in the session engine, merged in the reduction.

The sample is a GGX whose specular peak is ~4,000 × its diffuse level: no single exposure
holds both, so one HDR capture must bracket the peak poses short and the diffuse ones long.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import grid_plan_text

from acquisition import api
from acquisition.api.truth import truth_table
from acquisition.reduction.point import reduce_session
from acquisition.session.engine import POSE, StepEvent
from acquisition.session.folder import JOURNAL_FILE
from acquisition.session.hdr import HDR_DONE_META, hdr_group
from acquisition.session.journal import Journal
from acquisition.session.observers import Observer
from drivers.errors import SafetyStop

SHINY = "ggx:albedo=0.02,alpha=0.06,f0=0.9"
DIFFUSE = 0.02 / np.pi
HDR_PLAN = grid_plan_text((20, 40, 20), (20, 40, 20), (0, 180, 90), name="hdr") + (
    "[capture]\nhdr = true\ntarget_snr = 30\n"
)


@pytest.fixture(scope="module")
def plan(tmp_path_factory: pytest.TempPathFactory) -> Path:
    path = tmp_path_factory.mktemp("hdr-plan") / "plan-hdr.toml"
    path.write_text(HDR_PLAN)
    return path


@pytest.fixture(scope="module")
def shiny(rig_sim_path_module: Path, plan: Path, tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("hdr") / "shiny"
    api.capture(rig_sim_path_module, plan, out, material=SHINY, seed=5)
    return out


@pytest.fixture(scope="module")
def rig_sim_path_module() -> Path:
    return Path(__file__).resolve().parent.parent / "examples" / "rig-sim.toml"


def _groups(session: Path) -> dict[int, list]:
    with Journal(session / JOURNAL_FILE) as journal:
        groups: dict[int, list] = {}
        for rec in journal.steps():
            if rec.kind == POSE:
                groups.setdefault(hdr_group(rec.note), []).append(rec)
        assert all(journal.meta(f"{HDR_DONE_META}{g}") == len(r) for g, r in groups.items())
    return groups


def test_one_hdr_capture_holds_peak_and_diffuse(shiny: Path) -> None:
    table = reduce_session(shiny).table
    truth = truth_table(shiny)
    measured = table.count > 0
    rel = np.mean(np.abs(table.mean - truth.mean) / truth.mean, axis=-1)[measured]
    level = truth.mean[measured].mean(axis=-1)
    # Fresnel's f0 = 0.9 keeps the lobe's tail at ~2 × albedo/π away from the mirror poses.
    peak, diffuse = level > 1000 * DIFFUSE, level < 4 * DIFFUSE
    assert peak.sum() >= 2 and diffuse.sum() >= 3
    assert level.max() / level.min() > 2000  # the dynamic range one capture must span
    assert np.all(rel[peak] <= 0.03), rel[peak]
    assert np.all(rel[diffuse] <= 0.02), rel[diffuse]
    # No saturated plateau: the peak bins keep their ratio to each other (a clipped frame
    # would put them all near the sensor's ceiling).
    ratio = table.mean[measured][peak][:, 1] / truth.mean[measured][peak][:, 1]
    assert np.ptp(ratio) < 0.04


def test_brackets_are_journaled_one_row_per_frame(shiny: Path) -> None:
    groups = _groups(shiny)
    assert None not in groups  # every pose frame belongs to a bracket
    sizes = {g: len(r) for g, r in groups.items()}
    assert max(sizes.values()) >= 3  # the peak poses went short
    for g, recs in groups.items():
        assert [r.step for r in recs] == list(range(g, g + len(recs)))
        assert [r.note for r in recs] == [f"hdr={g}:{k}" for k in range(len(recs))]
        assert len({tuple(sorted(r.joints_cmd.items())) for r in recs}) == 1
        exposures = [r.exposure_s for r in recs]
        assert len(set(exposures)) == len(exposures)  # each frame a different exposure


class _StopAt(Observer):
    """Interrupts the run (like Ctrl-C) right after the frame noted ``note``."""

    def __init__(self, note: str) -> None:
        self.note = note

    def step(self, event: StepEvent) -> None:
        if event.record.note == self.note:
            raise KeyboardInterrupt


def test_a_bracket_interrupted_part_way_is_reshot_whole(
    shiny: Path, rig_sim_path_module: Path, plan: Path, tmp_path: Path
) -> None:
    groups = _groups(shiny)
    g, recs = max(groups.items(), key=lambda kv: len(kv[1]))
    out = tmp_path / "resumed"
    with pytest.raises(SafetyStop):
        api.capture(rig_sim_path_module, plan, out, material=SHINY, seed=5,
                    observers=[_StopAt(f"hdr={g}:1")])
    with Journal(out / JOURNAL_FILE) as journal:
        assert journal.meta(f"{HDR_DONE_META}{g}") is None
        assert journal.record(g + 2) is None
    api.resume(out)
    again = _groups(out)
    assert [len(r) for r in again.values()] == [len(r) for r in groups.values()]
    assert [r.attempts for r in again[g][:2]] == [2, 2]  # shot again, not kept
    assert [r.exposure_s for r in again[g]] == [r.exposure_s for r in recs]
    a, b = reduce_session(shiny).table, reduce_session(out).table
    np.testing.assert_array_equal(a.count, b.count)
    np.testing.assert_allclose(a.mean, b.mean, rtol=1e-12)
