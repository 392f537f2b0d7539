"""gonio info: a session's progress, timing, errors and drift; a table's coverage and provenance."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from conftest import TINY_PLAN_ARGS, grid_plan_text

from acquisition import api
from acquisition.cli import main
from acquisition.formats.merl import write_merl
from acquisition.session.status import session_status
from acquisition.tables import IsotropicTable
from drivers.errors import SafetyStop

PLAN = grid_plan_text(*TINY_PLAN_ARGS, name="tiny", reference_every=2)


def test_session_info_tracks_an_interrupted_then_resumed_capture(
    rig_sim_path: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    plan = tmp_path / "plan.toml"
    plan.write_text(PLAN)
    out = tmp_path / "s"

    def stop_at_three(done: int, total: int, record: object) -> None:
        if done == 3:
            raise KeyboardInterrupt

    with pytest.raises(SafetyStop):
        api.capture(rig_sim_path, plan, out, material="lambert:albedo=0.5", progress=stop_at_three)
    st = session_status(out)
    assert (st.done, st.total) == (3, 7)  # ref, 2 poses, ref, 2 poses, ref
    assert st.by_kind == {"reference": (1, 3), "pose": (2, 4)}
    assert st.runs == 1 and st.device_s is not None and st.device_s > 0
    assert [e[3] for e in st.events] == ["interrupted by the operator"]
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "3/7 steps done" in text and f"gonio resume {out}" in text
    assert "interrupted by the operator" in text

    assert main(["resume", str(out), "--no-reduce"]) == 0
    said = capsys.readouterr().out  # the whole session's steps; this run's own rig time
    assert "7 steps done; this run took" in said and "s of rig time" in said
    st = session_status(out)
    assert (st.done, st.total, st.runs) == (7, 7, 2)
    assert st.drift_pct is not None and 0 <= st.drift_pct < 2  # a steady simulated lamp
    device_first = st.device_s
    assert device_first is not None and device_first > 0
    assert main(["info", str(out)]) == 0
    text = capsys.readouterr().out
    assert "7/7 steps done (100 %)" in text and "drift" in text and "2 run(s)" in text


def test_table_info_reports_coverage_units_provenance(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    t = IsotropicTable(np.arange(0, 91, 30.0), np.arange(0, 91, 30.0), np.arange(0, 181, 90.0),
                       provenance={"material": "felt", "rig": "sim"})
    t.add([10, 10, 50], [10, 40, 40], [45, 45, 135], np.full((3, 3), 0.2))
    path = tmp_path / "t.h5"
    t.save_h5(path)
    assert main(["info", str(path)]) == 0
    text = capsys.readouterr().out
    assert "3 × 3 × 2" in text and "3 measured bins, 16.7 %" in text
    assert "1/sr" in text and "material = felt" in text and "samples   3" in text

    values = np.full((90, 90, 180, 3), np.nan)
    values[:45] = 0.5
    merl = tmp_path / "m.binary"
    write_merl(merl, values)
    assert main(["info", str(merl)]) == 0
    text = capsys.readouterr().out
    assert "MERL binary" in text and "729000 measured bins, 50.0 %" in text
    assert "0.5 … 0.5 sr⁻¹" in text


def test_info_of_a_missing_path_names_every_kind_it_reads(tmp_path, capsys) -> None:
    assert main(["info", str(tmp_path / "nowhere")]) != 0
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "does not exist" in err
    assert "session folder" in err and ".h5" in err and "MERL" in err
