"""Partial tables: any split of a session's frames into partials, merged in any order and
grouping, finishes into the table `gonio reduce` writes, byte for byte (a point session and an
image-based one); naive float partials would not; partial files save atomically, refuse other
versions; a SIGKILLed image-based `gonio reduce` resumes from its checkpoint to the same file."""

from __future__ import annotations

import os
import random
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from conftest import EXAMPLES
from test_fused_binning import assert_same_tables
from test_image_capture import small_rig  # rig-sphere-sim.toml at 300 × 300 px: fast

from acquisition import api
from acquisition.geometry.kinematics import poses_from_directions
from acquisition.reduction.checkpoint import checkpoint_path
from acquisition.reduction.image import ImageReducer, bin_frames
from acquisition.reduction.point import PointReducer
from acquisition.tables.partial import (
    PartialError,
    ReductionPartial,
    load_partial,
    merge_all,
    save_partial,
)

GONIO = Path(sys.executable).with_name("gonio")
MATERIAL = "ggx:albedo=0.2,alpha=0.25,f0=0.04"


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """plan-quick on rig-sim.toml and plan-sphere on the sphere rig, each with the table a
    plain `gonio reduce` writes."""
    root = tmp_path_factory.mktemp("partials")
    out = {"quick": root / "quick", "sphere": root / "sphere"}
    api.capture(EXAMPLES / "rig-sim.toml", EXAMPLES / "plan-quick.toml", out["quick"],
                material=MATERIAL, seed=4)
    api.capture(small_rig(root), EXAMPLES / "plan-sphere.toml", out["sphere"],
                material=MATERIAL, seed=5)
    for name in ("quick", "sphere"):
        out[f"{name}-table"] = root / f"{name}.h5"
        api.reduce(out[name], out[f"{name}-table"])
    return out


def table_contents(path: Path) -> dict[str, bytes]:
    """Every dataset's bytes and every attribute of a table file but the provenance (it
    records when the table was reduced)."""
    out: dict[str, bytes] = {}

    def visit(name: str, obj: h5py.HLObject) -> None:
        if isinstance(obj, h5py.Dataset):
            out[name] = obj[()].tobytes() + str(obj.dtype).encode() + str(obj.shape).encode()
        out.update({f"{name}@{k}": repr(v).encode() for k, v in obj.attrs.items()})

    with h5py.File(path, "r") as f:
        f.visititems(visit)
        out.update({f"@{k}": repr(v).encode() for k, v in f.attrs.items() if k != "provenance"})
    return out


def random_merge(parts: list[ReductionPartial], rng: random.Random) -> ReductionPartial:
    """Merge in a random order and a random grouping (a random binary tree)."""
    parts = parts[:]
    rng.shuffle(parts)
    while len(parts) > 1:
        k = rng.randrange(len(parts) - 1)
        parts[k:k + 2] = [parts[k].merge(parts[k + 1])]
    return parts[0]


def random_groups(steps: list[int], rng: random.Random) -> list[list[int]]:
    steps = steps[:]
    rng.shuffle(steps)
    cuts = sorted(rng.sample(range(1, len(steps)), rng.randrange(1, min(6, len(steps)))))
    return [steps[a:b] for a, b in zip([0, *cuts], [*cuts, len(steps)], strict=True)]


def test_point_session_partials_merge_to_the_reduced_table(sessions, tmp_path):
    reducer = PointReducer.open(sessions["quick"])
    want = table_contents(sessions["quick-table"])
    rng = random.Random(7)
    splits = [[[s] for s in reducer.steps]] + [random_groups(reducer.steps, rng) for _ in range(2)]
    for k, groups in enumerate(splits):
        merged = random_merge([reducer.partial(g) for g in groups], rng)
        assert merged.steps == frozenset(reducer.steps)
        path = tmp_path / f"split{k}.h5"
        reducer.reduction(merged).table.save_h5(path)
        assert table_contents(path) == want, f"split {k}: {[len(g) for g in groups]}"


def test_image_session_partials_merge_to_the_reduced_table(sessions, tmp_path):
    reducer = ImageReducer.open(sessions["sphere"])
    frames = {f[0].step: f for f in reducer.frames}
    singles = {s: reducer.partial([f]) for s, f in frames.items()}  # one partial per frame
    want = table_contents(sessions["sphere-table"])
    rng = random.Random(8)
    groupings = [random_merge(list(singles.values()), rng)]
    for _ in range(2):  # partials of several frames each
        groups = random_groups(list(frames), rng)
        groupings.append(random_merge([reducer.partial([frames[s] for s in g]) for g in groups],
                                      rng))
    for k, merged in enumerate(groupings):
        assert merged.steps == frozenset(frames)
        red = reducer.reduction(merged)
        path = tmp_path / f"split{k}.h5"
        red.table.save_h5(path, merl=red.merl)
        assert table_contents(path) == want, f"grouping {k}"
    assert sum(p.samples for p in singles.values()) == red.samples > 100_000


def test_frames_binned_from_their_pixels_are_the_reference_tables(sessions):
    """ImageReducer.reduce bins each frame straight from its pixels (pixelbinning; from the
    second frame on, the geometry starts while the frame is decoded); the reference path
    (every frame's samples, then the tables' own add methods) gives the same partials,
    samples and tallies, and so does a run whose geometry was started for another size."""
    reducer = ImageReducer.open(sessions["sphere"])
    rec, image = next(reducer.images(reducer.frames[:1]))
    assert reducer.bin_image(image, rec, *reducer.new_tables()) is not None  # the fast path
    fast, ref = reducer.new_tables(), reducer.new_tables()
    counts = [count for _, count, _ in reducer.reduce(reducer.frames, *fast)]
    ref_counts = []
    for fs in reducer.samples(reducer.frames):
        bin_frames([fs], *ref, None, 0, fused=False)
        ref_counts.append(fs.count)
    assert counts == ref_counts and sum(counts) > 100_000
    assert_same_tables(fast, ref)
    reducer.frame_shape = (7, 9)  # the geometry started for another image size is dropped
    again = reducer.new_tables()
    assert [count for _, count, _ in reducer.reduce(reducer.frames, *again)] == counts
    assert_same_tables(again, ref)


def test_running_sums_take_frames_in_any_order_and_each_once(sessions, tmp_path):
    """A Dask worker's running sums (PartialBuilder): frames added one call at a time, in a
    shuffled order, give the reduced table; a frame added twice is refused."""
    from acquisition.reduction.image import PartialBuilder
    from acquisition.tables.partial import PartialError

    reducer = ImageReducer.open(sessions["sphere"])
    frames = list(reducer.frames)
    random.Random(3).shuffle(frames)
    builder = PartialBuilder(reducer)
    for f in frames:
        builder.add([f])
    red = reducer.reduction(builder.partial())
    red.table.save_h5(tmp_path / "running.h5", merl=red.merl)
    assert table_contents(tmp_path / "running.h5") == table_contents(sessions["sphere-table"])
    with pytest.raises(PartialError, match="binned twice"):
        builder.add([frames[0]])


def test_naive_float_partials_would_depend_on_the_split(sessions):
    """The sphere's per-pixel samples summed per isotropic bin in float64 (what the tables did
    before): one sum over all samples, one partial per frame merged, and partials of half
    frames merged in two orders all disagree somewhere (so the tests above can fail). The
    exact partials agree bit for bit."""
    reducer = ImageReducer.open(sessions["sphere"])
    table, _ = reducer.new_tables()
    n_bins = table.count.size

    def floats(idx: np.ndarray, values: np.ndarray) -> np.ndarray:
        out = np.zeros((n_bins, 3))
        np.add.at(out, idx, values)
        return out

    per_frame, halves, exact, everything = [], [], [], []
    for fs in reducer.samples(reducer.frames):
        angles = poses_from_directions(fs.wi, fs.wo)
        idx = table.flat_index(angles[:, 0], angles[:, 1], angles[:, 2])
        keep = idx >= 0
        idx, values = idx[keep], fs.brdf[keep]
        everything.append((idx, values))
        per_frame.append(floats(idx, values))
        halves += [floats(idx[::2], values[::2]), floats(idx[1::2], values[1::2])]
        one, merl = reducer.new_tables()
        bin_frames([fs], one, merl, None, 0)
        exact.append(one.partial())
    sequential = floats(np.concatenate([i for i, _ in everything]),
                        np.concatenate([v for _, v in everything]))
    frames = sum(per_frame[1:], per_frame[0])
    assert np.count_nonzero(sequential != frames) > 10
    forward, backward = sum(halves[1:], halves[0]), sum(halves[-2::-1], halves[-1])
    assert np.count_nonzero(forward != backward) > 10
    a, b = exact[0], exact[-1]
    for p in exact[1:]:
        a = a.merge(p)
    for p in exact[-2::-1]:
        b = b.merge(p)
    assert a.values.same_as(b.values) and a.budget.sums.same_as(b.budget.sums)


def test_partial_files_round_trip_and_replace_atomically(sessions, tmp_path):
    reducer = ImageReducer.open(sessions["sphere"])
    first = reducer.partial(reducer.frames[:2])
    path = save_partial(tmp_path / "part.h5", first)
    back = load_partial(path)
    assert (back.key, back.steps, back.samples) == (first.key, first.steps, first.samples)
    for name, table in first.tables.items():
        assert back.tables[name].values.same_as(table.values)
        assert back.tables[name].dropped == table.dropped
    assert back.tables["isotropic"].budget.sums.same_as(first.tables["isotropic"].budget.sums)
    assert back.tables["isotropic"].budget.independent == first.tables["isotropic"].budget.independent
    # A crash (SIGKILL) in the middle of writing a bigger partial over it leaves the old one.
    code = textwrap.dedent(f"""
        import os, signal
        import acquisition.tables.partial as p
        from acquisition.reduction.image import ImageReducer
        r = ImageReducer.open({str(sessions["sphere"])!r})
        bigger = r.partial(r.frames[:4])
        write = p._write_sums
        def dying(group, sums):
            write(group, sums)
            os.kill(os.getpid(), signal.SIGKILL)
        p._write_sums = dying
        p.save_partial({str(path)!r}, bigger)
    """)
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, timeout=120)
    assert done.returncode == -signal.SIGKILL, done.stderr
    again = load_partial(path)
    assert again.steps == first.steps
    assert again.tables["merl"].values.same_as(first.tables["merl"].values)
    with pytest.raises(PartialError, match="holds|both hold"):
        first.merge(back)  # the same frames twice


def test_partials_from_other_versions_are_refused(sessions, tmp_path, monkeypatch):
    reducer = ImageReducer.open(sessions["sphere"])
    part = reducer.partial(reducer.frames[:1])
    here = __import__("acquisition.tables.partial", fromlist=["x"]).software_versions()
    monkeypatch.setattr("acquisition.tables.partial.software_versions",
                        lambda: {**here, "numba": "0.1.0"})
    path = save_partial(tmp_path / "old.h5", part)
    monkeypatch.undo()
    with pytest.raises(PartialError) as err:
        load_partial(path)
    line = str(err.value)
    assert "numba 0.1.0" in line and f"numba {here['numba']}" in line and "\n" not in line
    # gonio reduce refuses such a checkpoint in one line and writes no table.
    table = tmp_path / "t.h5"
    os.replace(path, checkpoint_path(table))
    done = subprocess.run([str(GONIO), "reduce", str(sessions["sphere"]), "-o", str(table)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode != 0 and not table.exists()
    assert done.stderr.strip().count("\n") == 0 and "numba 0.1.0" in done.stderr


def test_killed_image_reduction_resumes_to_the_same_table(sessions, tmp_path):
    table = tmp_path / "brdf.h5"
    checkpoint = checkpoint_path(table)
    argv = [str(GONIO), "reduce", str(sessions["sphere"]), "-o", str(table),
            "--checkpoint-every", "1", "--json"]
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while not checkpoint.exists() and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.01)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL, "the reduction ended before its first checkpoint"
    held = load_partial(checkpoint).steps
    assert 1 <= len(held) < 13 and not table.exists()
    done = subprocess.run(argv, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    report = __import__("json").loads(done.stdout)
    assert report["resumed_frames"] >= len(held) and report["frames"] == 13
    assert table_contents(table) == table_contents(sessions["sphere-table"])
    assert not checkpoint.exists()  # deleted once the table is written


def test_a_checkpoint_of_another_reduction_is_not_used(sessions, tmp_path):
    reducer = ImageReducer.open(sessions["sphere"])
    other = reducer.partial(reducer.frames[:3])
    table = tmp_path / "t.h5"
    save_partial(checkpoint_path(table), ReductionPartial("another session", other.steps,
                                                          other.tables, other.samples))
    red = api.reduce(sessions["sphere"], table)
    assert red.resumed_frames == 0
    assert table_contents(table) == table_contents(sessions["sphere-table"])
    with pytest.raises(PartialError, match="different reductions"):
        merge_all([other, ReductionPartial("x", frozenset({999}), other.tables)])
