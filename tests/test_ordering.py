"""Ordering: optimal configuration choice, near-optimal tours, valid lower bounds (checked
against brute force on small instances), unsafe moves avoided."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from acquisition.planning import ordering
from acquisition.planning.timing import AxisProfile, StepCosts, TimeModel

MODEL = TimeModel(
    {"a": AxisProfile(150.0, 600.0), "b": AxisProfile(150.0, 600.0), "c": AxisProfile(200.0, 400.0)},
    StepCosts(),
).for_joints(("a", "b", "c"))


def problem(configs: np.ndarray, start: np.ndarray | None = None, **kw: object) -> ordering.Problem:
    start = np.zeros(configs.shape[-1]) if start is None else start
    return ordering.Problem(configs, start, MODEL.move_s, 1.0 / np.array([600.0, 600.0, 400.0]),
                            reach=MODEL.reach_deg, **kw)


def random_problem(rng: np.random.Generator, n: int, k: int = 2) -> ordering.Problem:
    base = rng.uniform(-60, 60, (n, 1, 3))
    offsets = np.zeros((1, k, 3))
    offsets[0, 1:, 0] = rng.uniform(-80, 80, k - 1)  # other solutions: far on the first axis
    offsets[0, 1:, 2] = 180.0
    cfg = base + offsets
    cfg[rng.random((n, k)) < 0.2] = np.nan  # some poses lack a solution
    cfg[:, 0] = base[:, 0]  # every pose has at least one
    return problem(cfg)


def brute_force(p: ordering.Problem) -> float:
    """Optimal motion time over every order and every configuration choice."""
    n, k = p.configs.shape[:2]
    best = np.inf
    for perm in itertools.permutations(range(n)):
        for choice in itertools.product(range(k), repeat=n):
            pts = p.configs[list(perm), list(choice)]
            if np.isnan(pts).any():
                continue
            seq = np.vstack([p.start[None], pts])
            best = min(best, float(MODEL.move_s(seq[:-1], seq[1:]).sum()))
    return best


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_small_instances_against_brute_force(seed: int) -> None:
    p = random_problem(np.random.default_rng(seed), 6)
    opt = brute_force(p)
    sol = ordering.solve(p, time_budget_s=2.0)
    assert sol.motion_s == pytest.approx(ordering.path_motion_s(p, sol.order, sol.choice))
    assert sorted(sol.order.tolist()) == list(range(6))
    assert opt - 1e-9 <= sol.motion_s <= 1.25 * opt
    hk = ordering.held_karp_bound(p, sol.motion_s, time_budget_s=2.0)
    nearest = ordering.nearest_move_bound(p)
    assert 0 < nearest <= opt + 1e-9
    assert 0 < hk <= opt + 1e-9
    assert hk >= 0.8 * opt  # the 1-tree bound is close on these


def test_best_configurations_is_optimal_for_a_fixed_order() -> None:
    rng = np.random.default_rng(5)
    p = random_problem(rng, 7, k=3)
    order = rng.permutation(7)
    choice = ordering.best_configurations(p, order)
    best = np.inf
    for combo in itertools.product(range(3), repeat=7):
        c = np.empty(7, dtype=int)
        c[order] = combo
        if np.isnan(p.configs[np.arange(7), c]).any():
            continue
        best = min(best, ordering.path_motion_s(p, order, c))
    assert ordering.path_motion_s(p, order, choice) == pytest.approx(best)


def test_local_search_fixes_a_scrambled_grid() -> None:
    g = np.arange(0, 60, 4.0)
    pts = np.array([(x, y, 0.0) for x in g for y in g])[:, None, :]
    p = problem(pts)
    order = np.random.default_rng(1).permutation(len(pts))
    tour = ordering._Tour(p, order, np.zeros(len(pts), dtype=int))
    scrambled = tour.motion_s()
    ordering.local_search(tour, ordering._neighbours(tour, 8), deadline=np.inf)
    assert sorted(tour.t[1:-1].tolist()) == list(range(len(pts)))
    assert tour.pos[tour.t].tolist() == list(range(len(pts) + 2))
    improved = tour.motion_s()
    step = MODEL.move_s(np.zeros(3), np.array([4.0, 0, 0]))
    # A 15 × 15 grid needs at least 224 one-step moves (the start is a grid point).
    assert improved < scrambled / 2
    assert improved <= 1.25 * (len(pts) - 1) * step + MODEL.move_s(np.zeros(3), np.zeros(3))


def test_solve_beats_sorted_order_and_stays_near_the_bound() -> None:
    rng = np.random.default_rng(3)
    p = random_problem(rng, 400)
    sol = ordering.solve(p, time_budget_s=3.0)
    nn_order, nn_choice = ordering.nearest_neighbour(p)
    assert sol.motion_s <= ordering.path_motion_s(p, nn_order, nn_choice) + 1e-9
    sorted_order = np.lexsort(p.configs[:, 0, ::-1].T)
    naive = ordering.path_motion_s(p, sorted_order, ordering.best_configurations(p, sorted_order))
    assert sol.motion_s < 0.6 * naive
    hk = ordering.held_karp_bound(p, sol.motion_s, time_budget_s=3.0)
    assert hk <= sol.motion_s <= 1.25 * hk
    assert ordering.nearest_move_bound(p) <= hk


def test_unsafe_moves_are_avoided() -> None:
    # Two rows of points; moves across x = 0 are unsafe on the lower row (y < 5), as if the
    # camera swung through the light there; the upper row may cross.
    xs = np.concatenate([np.linspace(-50, -2, 13), np.linspace(2, 50, 13)])
    rows = [np.column_stack([xs, np.full_like(xs, y), np.zeros_like(xs)]) for y in (0.0, 10.0)]
    pts = np.vstack(rows)[:, None, :]

    def ok(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        crossing = np.sign(a[:, 0]) * np.sign(b[:, 0]) < 0
        low = (a[:, 1] < 5) | (b[:, 1] < 5)
        return ~(crossing & low)

    p = problem(pts, start=np.array([-50.0, 0, 0]), transit_ok=ok)
    plain = ordering.solve(problem(pts, start=np.array([-50.0, 0, 0])), time_budget_s=2.0)
    seq = np.vstack([p.start[None], pts[plain.order, 0]])
    assert not ok(seq[:-1], seq[1:]).all()  # the unconstrained order does cross low
    sol = ordering.solve(p, time_budget_s=2.0)
    assert sol.unsafe_moves == 0
    seq = np.vstack([p.start[None], pts[sol.order, 0]])
    assert ok(seq[:-1], seq[1:]).all()
    assert sol.motion_s <= 1.3 * plain.motion_s


def test_dense_costs_never_overstate_a_move() -> None:
    p = random_problem(np.random.default_rng(9), 30, k=3)
    w = ordering.dense_costs(p)
    assert np.allclose(w, w.T)
    for i, j in [(0, 1), (4, 17), (29, 3)]:
        a, b = p.configs[i], p.configs[j]
        true = np.nanmin(MODEL.move_s(a[:, None, :], b[None, :, :]))
        assert true * (1 - 1e-5) <= w[i, j] <= true
