"""Dask distributed reduction: `gonio reduce SESSION... --scheduler/--workers` writes, for a
point session (rig-sim + plan-quick) and an image-based sphere session in one call, the tables
a local `gonio reduce` writes, bit for bit (every dataset, the MERL export); workers of other
versions are refused before any work; a bad frame or a failure on a worker is one line, a
non-zero exit and no table; clashing outputs and a missing extra are one line too."""

from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path

import h5py
import pytest
from conftest import EXAMPLES
from distributed import Client, LocalCluster
from test_bad_frames import _one_line, _truncate
from test_image_capture import plan_file, small_rig
from test_partials import table_contents

from acquisition import api
from acquisition.cli import main
from acquisition.tables.partial import software_versions

MATERIAL = "ggx:albedo=0.2,alpha=0.25,f0=0.04"


@pytest.fixture(scope="module")
def cluster() -> Client:
    with LocalCluster(n_workers=2, processes=True, threads_per_worker=1, dashboard_address=None,
                      silence_logs=logging.ERROR,
                      scheduler_kwargs={"dashboard_address": "127.0.0.1:0"}) as c, \
            Client(c) as client:
        yield client


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """plan-quick on rig-sim.toml (point) and three poses of the small sphere rig (image),
    each with the table a plain local `gonio reduce` writes."""
    root = tmp_path_factory.mktemp("distributed")
    out = {"quick": root / "quick", "sphere": root / "sphere"}
    api.capture(EXAMPLES / "rig-sim.toml", EXAMPLES / "plan-quick.toml", out["quick"],
                material=MATERIAL, seed=4)
    api.capture(small_rig(root), plan_file(root, [[15, 45, 0], [30, 45, 180], [60, 45, 180]]),
                out["sphere"], material=MATERIAL, seed=5)
    for name in ("quick", "sphere"):
        out[f"{name}-table"] = root / f"{name}.h5"
        assert main(["reduce", str(out[name]), "-o", str(out[f"{name}-table"])]) == 0
    return out


def provenance(path: Path) -> dict[str, object]:
    """A table's provenance but the time it was reduced."""
    with h5py.File(path, "r") as f:
        prov = json.loads(f.attrs["provenance"])
    prov.pop("reduced_at")
    return prov


def assert_same_table(path: Path, reference: Path) -> None:
    assert table_contents(path) == table_contents(reference)
    assert provenance(path) == provenance(reference)


def test_distributed_tables_are_the_local_ones_bit_for_bit(sessions, cluster, tmp_path, capsys):
    out = tmp_path / "tables"
    assert main(["reduce", str(sessions["quick"]), str(sessions["sphere"]), "-o", str(out),
                 "--scheduler", cluster.scheduler.address, "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert [Path(t["table"]).name for t in report["tables"]] == ["quick.h5", "sphere.h5"]
    assert report["tables"][0]["frames"] > 100 and report["tables"][1]["frames"] == 3
    for name in ("quick", "sphere"):
        assert_same_table(out / f"{name}.h5", sessions[f"{name}-table"])
    with h5py.File(out / "sphere.h5", "r") as f:
        assert f["merl/count"][()].sum() > 10_000  # the sphere's per-pixel MERL table
    merl = [api.export_table(t, "merl", tmp_path / f"{k}.binary").path
            for k, t in enumerate((out / "sphere.h5", sessions["sphere-table"]))]
    assert merl[0].read_bytes() == merl[1].read_bytes()
    assert sorted(p.name for p in out.iterdir()) == ["quick.h5", "sphere.h5"]  # nothing else


def test_workers_start_a_local_cluster_with_one_bar_over_all_frames(sessions, tmp_path):
    seen: list[tuple[int, int]] = []
    results = api.reduce_many([sessions["sphere"]], tmp_path / "t.h5", workers=1,
                              progress=lambda done, total: seen.append((done, total)))
    assert [r.frames for r in results] == [3] and seen[-1] == (3, 3)
    assert [d for d, _ in seen] == [1, 2, 3]
    assert_same_table(tmp_path / "t.h5", sessions["sphere-table"])


def _numba_threads() -> int:
    import numba

    return numba.get_num_threads()


def test_local_workers_share_the_cores_for_numbas_threads():
    """``--workers 2``: each worker process runs numba's kernels on its share of the cores
    (one thread per core in all), not on every core each."""
    from acquisition.reduction.distributed import dask_client

    before = os.environ.get("NUMBA_NUM_THREADS")
    with dask_client(workers=2) as client:
        threads = client.run(_numba_threads)
    assert len(threads) == 2
    assert set(threads.values()) == {max(1, (os.cpu_count() or 1) // 2)}
    assert os.environ.get("NUMBA_NUM_THREADS") == before  # this process's is left alone


def test_workers_of_other_versions_are_refused_before_any_work(sessions, cluster, tmp_path,
                                                               capsys):
    def old_numpy() -> None:  # runs on one worker (pickled by value: a local function)
        import importlib.metadata

        import acquisition.tables.partial as p
        p.version = lambda name: "1.0.0" if name == "numpy" else importlib.metadata.version(name)

    def restore() -> None:
        import importlib.metadata

        import acquisition.tables.partial as p
        p.version = importlib.metadata.version

    worker = sorted(cluster.scheduler_info()["workers"])[0]
    cluster.run(old_numpy, workers=[worker])
    try:
        assert main(["reduce", str(sessions["sphere"]), "-o", str(tmp_path / "t.h5"),
                     "--scheduler", cluster.scheduler.address]) == 2
    finally:
        cluster.run(restore, workers=[worker])
    line = _one_line(capsys.readouterr().err)
    here = software_versions()
    assert worker in line and "numpy 1.0.0" in line and f"numpy {here['numpy']}" in line
    assert f"gonio {here['gonio']}" in line and f"numba {here['numba']}" in line
    assert not (tmp_path / "t.h5").exists()


def test_a_bad_frame_on_a_worker_is_gonios_one_line(sessions, cluster, tmp_path, capsys):
    """Two sessions with a truncated frame and a good one: the local error line for the
    first, the second named, exit code 2, no table for either, the good session's table."""
    copies = {}
    for name in ("sphere", "quick"):
        copies[name] = shutil.copytree(sessions[name], tmp_path / f"{name}-bad",
                                       ignore=shutil.ignore_patterns("*.h5"))
        _truncate(sorted((copies[name] / "frames").glob("*.dng"))[2])
    assert main(["reduce", str(copies["sphere"]), "-o", str(tmp_path / "local.h5")]) == 2
    local = _one_line(capsys.readouterr().err)
    out = tmp_path / "tables"
    assert main(["reduce", str(copies["sphere"]), str(copies["quick"]), str(sessions["sphere"]),
                 "-o", str(out), "--scheduler", cluster.scheduler.address]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(local.rstrip()) and "step-000002.dng" in line
    assert f"also failed: {copies['quick'].resolve()}" in line
    assert [p.name for p in out.iterdir()] == ["sphere.h5"]
    assert_same_table(out / "sphere.h5", sessions["sphere-table"])


def test_a_failure_on_a_worker_is_one_line_naming_the_session(sessions, cluster, tmp_path,
                                                              capsys):
    """Binning (image) and reading a signal (point) crash on the workers: the first session's
    line, the second named, the rest of its frames cancelled, no table."""
    def break_workers() -> None:  # runs on the workers (pickled by value: a local function)
        import acquisition.reduction.distributed as dist
        from acquisition.reduction.image import PartialBuilder

        def crash(*_args):  # noqa: ANN002, ANN202
            raise RuntimeError("binning kernel crashed")

        PartialBuilder.real_add, dist.real_read_signal = PartialBuilder.add, dist.read_signal
        PartialBuilder.add = dist.read_signal = crash

    def restore() -> None:
        import acquisition.reduction.distributed as dist
        from acquisition.reduction.image import PartialBuilder

        PartialBuilder.add, dist.read_signal = PartialBuilder.real_add, dist.real_read_signal

    cluster.run(break_workers)
    try:
        assert main(["reduce", str(sessions["sphere"]), str(sessions["quick"]), "-o",
                     str(tmp_path / "lib"), "--scheduler", cluster.scheduler.address]) == 2
    finally:
        cluster.run(restore)
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"gonio: error: {sessions['sphere'].resolve()}: the reduction failed "
                           "on a Dask worker (RuntimeError: binning kernel crashed)")
    assert line.endswith(f"(also failed: {sessions['quick'].resolve()})")
    assert list((tmp_path / "lib").iterdir()) == []


@pytest.mark.parametrize("value", ["-3", "0", "abc"])
def test_a_bad_number_of_workers_is_named(value, tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(["reduce", str(tmp_path), "--workers", value])
    assert exit_.value.code == 2
    assert f"expected a number of workers ≥ 1, got '{value}'" in capsys.readouterr().err


def test_an_unreachable_scheduler_is_one_line(sessions, tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("acquisition.reduction.distributed.CONNECT_TIMEOUT_S", 0.5)
    assert main(["reduce", str(sessions["sphere"]), "-o", str(tmp_path / "t.h5"),
                 "--scheduler", "tcp://127.0.0.1:9"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert "cannot reach the Dask scheduler at tcp://127.0.0.1:9" in line
    assert not (tmp_path / "t.h5").exists()


def test_clashing_outputs_are_refused_before_reducing(sessions, tmp_path, capsys):
    twin = shutil.copytree(sessions["sphere"], tmp_path / "elsewhere" / "sphere",
                           ignore=shutil.ignore_patterns("*.h5"))
    for argv, words in (
            ([sessions["sphere"], twin, "-o", tmp_path / "lib"], ("would both write", "sphere.h5")),
            ([sessions["quick"], sessions["quick"]], ("would both write", "brdf.h5")),
            ([sessions["quick"], sessions["sphere"], "-o", tmp_path / "x.h5"],
             ("names one table", "a folder"))):
        assert main(["reduce", *map(str, argv), "--workers", "2"]) != 0
        line = _one_line(capsys.readouterr().err)
        assert all(w in line for w in words), line
    assert not (tmp_path / "lib").exists() and not (twin / "brdf.h5").exists()


def test_without_dask_local_reductions_work_and_workers_say_how_to_install(
        sessions, tmp_path, capsys, monkeypatch):
    for module in ("dask", "distributed"):
        monkeypatch.setitem(__import__("sys").modules, module, None)  # import raises
    out = tmp_path / "lib"
    assert main(["reduce", str(sessions["quick"]), str(sessions["sphere"]), "-o", str(out)]) == 0
    for name in ("quick", "sphere"):  # several sessions, reduced here one after the other
        assert_same_table(out / f"{name}.h5", sessions[f"{name}-table"])
    capsys.readouterr()
    assert main(["reduce", str(sessions["sphere"]), "-o", str(tmp_path / "t.h5"),
                 "--workers", "2"]) != 0
    assert "pip install 'gonio[distributed]'" in _one_line(capsys.readouterr().err)
    assert not (tmp_path / "t.h5").exists()


def test_a_worker_task_holds_numba_to_its_share(monkeypatch):
    """A spawned worker whose ``__main__`` imported gonio (so numba) before the nanny set
    NUMBA_NUM_THREADS has a pool of every core: each task thread is held to the share."""
    import threading

    import numba

    from acquisition.reduction.distributed import use_thread_share

    def threads_after(env: str | None) -> int:
        if env is None:
            monkeypatch.delenv("NUMBA_NUM_THREADS", raising=False)
        else:
            monkeypatch.setenv("NUMBA_NUM_THREADS", env)
        got: list[int] = []
        thread = threading.Thread(target=lambda: (use_thread_share(),
                                                  got.append(numba.get_num_threads())))
        thread.start()
        thread.join()
        return got[0]

    pool = numba.config.NUMBA_NUM_THREADS
    assert threads_after("1") == 1
    assert threads_after(None) == pool  # a remote cluster's worker: left alone
    assert threads_after(str(pool + 4)) == pool  # never above the pool numba has
