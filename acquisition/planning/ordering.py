"""Ordering poses to minimise motion time, and a lower bound on that time.

The problem is a shortest Hamiltonian path from the rig's start joints through every pose
(optionally ending at fixed joints), where each pose may be realised by several joint
configurations (inverse-kinematics solutions) and the cost of a move is the time model's
duration. :func:`solve` builds a tour by nearest neighbour over all configurations, improves
it with 2-opt and Or-opt moves on neighbour lists — evaluated for every candidate at once
with numpy and applied in batches of non-overlapping moves — and picks the best
configuration of every pose for the final order by dynamic programming.

:func:`lower_bound` gives a bound no order can beat, on the same metric with the cheapest
configuration pair for every move: the Held–Karp (Lagrangian 1-tree) bound for up to
``DENSE_MAX`` poses, otherwise the sum over poses of the cheapest move into each.

Moves whose swept path is unsafe (``transit_ok`` returns False) are avoided: the search
charges them :data:`PENALTY_S`, so they are the first edges it removes.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

Cost = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""Move duration (s) between joint arrays (…, J) and (…, J), broadcast."""

TransitCheck = Callable[[np.ndarray, np.ndarray], np.ndarray]
"""``ok(a (M, J), b (M, J)) -> (M,) bool``: False where the move a → b is unsafe on its way."""

PENALTY_S = 1.0e4
"""Cost charged to an unsafe move during the search."""

DENSE_MAX = 3000
"""Largest pose count for the dense Held–Karp bound (memory grows with its square)."""

_EPS = 1e-9


@dataclass
class Problem:
    """Poses with candidate configurations, the metric, and the fixed ends.

    Parameters
    ----------
    configs:
        (N, K, J) joint configurations per pose (degrees), NaN rows where a pose has fewer.
    start:
        (J,) joints before the first pose.
    cost:
        The time metric.
    scale:
        (J,) weights making the Chebyshev distance of scaled joints track the metric (used
        only to find candidate neighbours; 0 for joints that cost no time).
    finish:
        (J,) joints to end at, or None for a free end.
    transit_ok:
        Optional swept-path safety check.
    """

    configs: np.ndarray
    start: np.ndarray
    cost: Cost
    scale: np.ndarray
    finish: np.ndarray | None = None
    transit_ok: TransitCheck | None = None
    reach: Callable[[np.ndarray], np.ndarray] | None = None
    """``reach(t (M,)) -> (M, J)``: farthest travel of each joint within t seconds (the
    inverse of the metric per joint); lets :func:`nearest_move_bound` prove a neighbour
    search complete. Without it every pair is compared."""

    @property
    def n(self) -> int:
        return len(self.configs)

    @property
    def valid(self) -> np.ndarray:
        """(N, K) True where a configuration exists."""
        return ~np.any(np.isnan(self.configs), axis=-1)


@dataclass
class Ordering:
    """A solution: visiting order, configuration slot per pose, and its motion time (s)."""

    order: np.ndarray
    choice: np.ndarray
    motion_s: float
    unsafe_moves: int = 0


# ---------------------------------------------------------------------------- tour state
class _Tour:
    """Positions 0..N+1: the start node (index N), the poses, the end node (index N+1)."""

    def __init__(self, problem: Problem, order: np.ndarray, choice: np.ndarray) -> None:
        self.p = problem
        self.forbidden: set[int] = set()
        n = problem.n
        self.n = n
        self.free_end = problem.finish is None
        j = problem.configs.shape[-1]
        self.points = np.empty((n + 2, j))
        self.set_choice(choice)
        self.t = np.concatenate([[n], order, [n + 1]]).astype(np.int64)
        self.pos = np.empty(n + 2, dtype=np.int64)
        self.pos[self.t] = np.arange(n + 2)

    def set_choice(self, choice: np.ndarray) -> None:
        n = self.n
        self.choice = np.asarray(choice, dtype=np.int64)
        self.forbidden = set()  # unsafe pairs depend on the configurations
        self.points[:n] = self.p.configs[np.arange(n), self.choice]
        self.points[n] = self.p.start
        self.points[n + 1] = self.p.start if self.p.finish is None else self.p.finish

    def w(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Move times between nodes a and b (index arrays)."""
        c = self.p.cost(self.points[a], self.points[b])
        if self.free_end:
            c = np.where((a == self.n + 1) | (b == self.n + 1), 0.0, c)
        return c

    def key(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        return lo * (self.n + 2) + hi

    def edge_costs(self) -> np.ndarray:
        t = self.t
        e = self.w(t[:-1], t[1:])
        if self.forbidden:
            bad = np.isin(self.key(t[:-1], t[1:]), np.fromiter(self.forbidden, np.int64))
            e = e + PENALTY_S * bad
        return e

    def motion_s(self) -> float:
        t = self.t
        return float(self.w(t[:-1], t[1:]).sum())

    def check_transits(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """True where the moves a → b are safe; unsafe pairs are remembered as forbidden."""
        ok = np.ones(len(a), dtype=bool)
        if self.p.transit_ok is None or not len(a):
            return ok
        real = ~(self.free_end & ((a == self.n + 1) | (b == self.n + 1)))
        if real.any():
            ok[real] = self.p.transit_ok(self.points[a[real]], self.points[b[real]])
        self.forbidden.update(self.key(a[~ok], b[~ok]).tolist())
        return ok


# ---------------------------------------------------------------------------- construction
def nearest_neighbour(problem: Problem, k: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """Greedy tour: from the start, always the cheapest move to a configuration of an
    unvisited pose. Returns (order (N,), choice (N,)).

    Every configuration's ``k`` nearest others are found at once (k-d tree on the scaled
    joints, re-ranked by the true metric); a step takes the first unvisited one of its list,
    and only when the whole list is visited searches what is left.
    """
    from scipy.spatial import cKDTree

    n = problem.n
    if n == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    pose_of, slot_of = np.nonzero(problem.valid)  # flat configurations, grouped by pose
    first = np.searchsorted(pose_of, np.arange(n))
    last = np.searchsorted(pose_of, np.arange(n), side="right")
    flat = problem.configs[pose_of, slot_of]
    scaled = np.nan_to_num(flat * problem.scale)
    f = len(flat)
    kq = min(k + problem.configs.shape[1], f)
    _, nb = cKDTree(scaled).query(scaled, k=kq, p=np.inf)
    nb = nb.reshape(f, kq)
    cost = problem.cost(flat[:, None, :], flat[nb])
    nb = np.take_along_axis(nb, np.argsort(cost, axis=1), axis=1)
    lists = nb.tolist()
    pose_list = pose_of.tolist()
    visited = bytearray(n)
    remaining = np.ones(f, dtype=bool)
    alive = np.arange(f)
    tree = None
    left = f
    order = np.empty(n, dtype=np.int64)
    choice = np.empty(n, dtype=np.int64)
    cur = -1  # the start
    for step in range(n):
        best = -1
        if cur >= 0:
            for c in lists[cur]:
                if not visited[pose_list[c]]:
                    best = c
                    break
        if best < 0:  # search every configuration left (a k-d tree of them, rebuilt as it shrinks)
            if tree is None or left < len(alive) // 2:
                alive = np.flatnonzero(remaining)
                tree = cKDTree(scaled[alive])
            here = problem.start if cur < 0 else flat[cur]
            q = np.nan_to_num(here * problem.scale)
            idx = np.zeros(0, dtype=np.int64)
            for kk in (4 * k, 32 * k, len(alive)):
                kk = min(kk, len(alive))
                _, got = tree.query(q, k=kk, p=np.inf)
                got = alive[np.atleast_1d(got)]
                idx = got[remaining[got]]
                if len(idx) or kk == len(alive):
                    break
            best = int(idx[int(np.argmin(problem.cost(here[None, :], flat[idx])))])
        pose = pose_list[best]
        order[step], choice[pose] = pose, slot_of[best]
        visited[pose] = 1
        lo, hi = first[pose], last[pose]
        left -= int(remaining[lo:hi].sum())
        remaining[lo:hi] = False
        cur = best
    return order, choice


# ---------------------------------------------------------------------------- configurations
def best_configurations(problem: Problem, order: np.ndarray,
                        forbidden: set[tuple[int, int, int, int]] | None = None) -> np.ndarray:
    """The configuration of every pose minimising the motion time of ``order`` (dynamic
    programming over the sequence). ``forbidden`` holds (pose a, slot, pose b, slot) moves
    that may not be used."""
    n = problem.n
    if n == 0:
        return np.zeros(0, np.int64)
    c = problem.configs[order]  # (N, K, J)
    kk = c.shape[1]
    first = problem.cost(problem.start[None, :], c[0])  # (K,)
    first = np.where(np.isnan(first), np.inf, first)
    trans = problem.cost(c[:-1, :, None, :], c[1:, None, :, :])  # (N-1, K, K)
    trans = np.where(np.isnan(trans), np.inf, trans)
    if forbidden:
        where = {int(p): i for i, p in enumerate(order)}
        for a, ka, b, kb in forbidden:
            ia, ib = where.get(a), where.get(b)
            if ia is not None and ib is not None and ib == ia + 1:
                trans[ia, ka, kb] = np.inf
            elif ia is not None and ib is not None and ia == ib + 1:
                trans[ib, kb, ka] = np.inf
    last = np.zeros(kk)
    if problem.finish is not None:
        last = problem.cost(c[-1], problem.finish[None, :])
        last = np.where(np.isnan(last), np.inf, last)
    best = first.copy()
    back = np.zeros((n, kk), dtype=np.int64)
    for i in range(n - 1):
        tot = best[:, None] + trans[i]
        back[i + 1] = np.argmin(tot, axis=0)
        best = tot[back[i + 1], np.arange(kk)]
    best = best + last
    choice = np.empty(n, dtype=np.int64)
    choice[-1] = int(np.argmin(best))
    for i in range(n - 1, 0, -1):
        choice[i - 1] = back[i, choice[i]]
    out = np.empty(n, dtype=np.int64)
    out[order] = choice
    return out


# ---------------------------------------------------------------------------- local search
def _neighbours(tour: _Tour, k: int) -> np.ndarray:
    """(N, k) nearest pose nodes of each pose node under the current configurations."""
    from scipy.spatial import cKDTree

    n = tour.n
    k = min(k, n - 1)
    if k <= 0:
        return np.zeros((n, 0), dtype=np.int64)
    scaled = tour.points[:n] * tour.p.scale
    tree = cKDTree(scaled)
    q = min(2 * k + 1, n)
    _, idx = tree.query(scaled, k=q, p=np.inf)
    idx = idx.reshape(n, q)
    cost = tour.w(np.repeat(np.arange(n), q).reshape(n, q), idx)
    cost[idx == np.arange(n)[:, None]] = np.inf
    pick = np.argsort(cost, axis=1)[:, :k]
    return np.take_along_axis(idx, pick, axis=1)


def _two_opt_candidates(tour: _Tour, e: np.ndarray, nbr: np.ndarray, active: np.ndarray):
    """Gains and spans (i, j) of 2-opt moves reversing t[i+1..j] for active nodes."""
    t, pos, n = tour.t, tour.pos, tour.n
    a = active
    c = nbr[a]  # (A, k)
    p = np.repeat(pos[a][:, None], c.shape[1], axis=1)
    q = pos[c]
    out_i, out_j = [], []
    for shift in (0, 1):  # successor pairing, predecessor pairing
        i = np.minimum(p, q) - shift
        j = np.maximum(p, q) - shift
        ok = (i >= 0) & (j <= n) & (j >= i + 2)
        out_i.append(i[ok])
        out_j.append(j[ok])
    i = np.concatenate(out_i)
    j = np.concatenate(out_j)
    if not len(i):
        return np.zeros(0), i, j
    gain = e[i] + e[j] - tour.w(t[i], t[j]) - tour.w(t[i + 1], t[j + 1])
    return gain, i, j


def _or_opt_candidates(tour: _Tour, e: np.ndarray, nbr: np.ndarray, active: np.ndarray):
    """Gains of moving segments t[s..s+L-1] (L ≤ 3) between t[q], t[q+1], reversed or not."""
    t, pos, n = tour.t, tour.pos, tour.n
    gains, ss, ls, qs, revs = [], [], [], [], []
    act_pos = pos[active]
    for length in (1, 2, 3):
        # segments touching an active node
        s = np.unique(np.concatenate([act_pos - d for d in range(-1, length + 1)]))
        s = s[(s >= 1) & (s + length - 1 <= n)]
        if not len(s):
            continue
        f, l_ = t[s], t[s + length - 1]
        prev, nxt = t[s - 1], t[s + length]
        removal = e[s - 1] + e[s + length - 1] - tour.w(prev, nxt)
        ends = np.concatenate([nbr[f], nbr[l_]], axis=1)  # (S, 2k)
        for before in (0, 1):
            q = pos[ends] - before  # insert after the neighbour, or before it
            srep = np.repeat(s[:, None], q.shape[1], axis=1)
            ok = (q >= 0) & (q <= n) & ((q < srep - 1) | (q > srep + length - 1))
            qq, sidx = q[ok], np.nonzero(ok)[0]
            if not len(qq):
                continue
            x, y = t[qq], t[qq + 1]
            fi, li = f[sidx], l_[sidx]
            fwd = tour.w(x, fi) + tour.w(li, y)
            rev = tour.w(x, li) + tour.w(fi, y)
            use_rev = rev < fwd
            ins = np.minimum(fwd, rev) - e[qq]
            gains.append(removal[sidx] - ins)
            ss.append(s[sidx])
            ls.append(np.full(len(qq), length))
            qs.append(qq)
            revs.append(use_rev)
    if not gains:
        z = np.zeros(0, dtype=np.int64)
        return np.zeros(0), z, z, z, z.astype(bool)
    return (np.concatenate(gains), np.concatenate(ss), np.concatenate(ls), np.concatenate(qs),
            np.concatenate(revs))


STALL_ROUNDS = 4
"""Local-search rounds without a lower tour cost before the search stops."""


@dataclass
class _Moves:
    """Candidate 2-opt (kind 0: reverse t[i+1..j]) and Or-opt (kind 1: move segment
    t[s..s+len-1] after position q, maybe reversed) moves, with their estimated gains (s) and
    the span of tour positions each reads or rewrites."""

    kind: np.ndarray
    gain: np.ndarray
    span_lo: np.ndarray
    span_hi: np.ndarray
    a1: np.ndarray
    a2: np.ndarray
    a3: np.ndarray
    a4: np.ndarray


def _candidate_moves(tour: _Tour, nbr: np.ndarray, active: np.ndarray) -> _Moves:
    e = tour.edge_costs()
    g2, i2, j2 = _two_opt_candidates(tour, e, nbr, active)
    go, so, lo_, qo, ro = _or_opt_candidates(tour, e, nbr, active)
    return _Moves(
        kind=np.concatenate([np.zeros(len(g2), np.int8), np.ones(len(go), np.int8)]),
        gain=np.concatenate([g2, go]),
        span_lo=np.concatenate([i2, np.minimum(so - 1, qo)]),
        span_hi=np.concatenate([j2 + 1, np.maximum(so + lo_, qo + 1)]),
        a1=np.concatenate([i2, so]),
        a2=np.concatenate([j2, lo_]),
        a3=np.concatenate([np.zeros_like(i2), qo]),
        a4=np.concatenate([np.zeros(len(i2), bool), ro]),
    )


def _non_overlapping(moves: _Moves, n: int, max_batch: int) -> np.ndarray:
    """The best-gaining improving moves whose spans do not overlap (at most ``max_batch``)."""
    good = np.flatnonzero(moves.gain > _EPS)
    good = good[np.argsort(-moves.gain[good])][: 4 * max_batch]
    occupied = np.zeros(n + 2, dtype=bool)
    chosen = []
    for m in good:
        lo, hi = moves.span_lo[m], moves.span_hi[m]
        if occupied[lo:hi + 1].any():
            continue
        occupied[lo:hi + 1] = True
        chosen.append(m)
        if len(chosen) >= max_batch:
            break
    return np.array(chosen, dtype=np.int64)


def _unsafe_moves(tour: _Tour, moves: _Moves, chosen: np.ndarray) -> set[int]:
    """The chosen moves that would create an edge with an unsafe transit."""
    t = tour.t
    new_a, new_b, owner = [], [], []
    for m in chosen:
        if moves.kind[m] == 0:
            i, j = moves.a1[m], moves.a2[m]
            pairs = [(t[i], t[j]), (t[i + 1], t[j + 1])]
        else:
            s, length, q, rev = moves.a1[m], moves.a2[m], moves.a3[m], moves.a4[m]
            f, l_ = t[s], t[s + length - 1]
            first, last = (l_, f) if rev else (f, l_)
            pairs = [(t[s - 1], t[s + length]), (t[q], first), (last, t[q + 1])]
        for x, y in pairs:
            new_a.append(x)
            new_b.append(y)
            owner.append(m)
    ok = tour.check_transits(np.array(new_a, np.int64), np.array(new_b, np.int64))
    return set(np.array(owner)[~ok].tolist())


def _apply(tour: _Tour, moves: _Moves, chosen: np.ndarray, skip: set[int]) -> list[int]:
    """Apply the chosen moves except ``skip``; returns the pose nodes whose edges changed."""
    t = tour.t
    touched: list[int] = []
    for m in chosen:
        if m in skip:
            continue
        if moves.kind[m] == 0:
            i, j = moves.a1[m], moves.a2[m]
            t[i + 1:j + 1] = t[i + 1:j + 1][::-1].copy()
            touched += [t[i], t[i + 1], t[j], t[j + 1]]
            continue
        s, length, q, rev = moves.a1[m], moves.a2[m], moves.a3[m], moves.a4[m]
        seg = t[s:s + length].copy()
        if rev:
            seg = seg[::-1]
        touched += [t[s - 1], t[s + length], t[q], t[q + 1], seg[0], seg[-1]]
        if q < s:
            mid = t[q + 1:s].copy()
            t[q + 1:q + 1 + length] = seg
            t[q + 1 + length:s + length] = mid
        else:
            mid = t[s + length:q + 1].copy()
            t[s:s + len(mid)] = mid
            t[s + len(mid):q + 1] = seg
    tour.pos[t] = np.arange(tour.n + 2)
    return touched


def local_search(tour: _Tour, nbr: np.ndarray, deadline: float, max_batch: int = 4000,
                 active: np.ndarray | None = None) -> None:
    """Apply improving 2-opt / Or-opt moves in batches until none is left or time is up.

    ``active`` limits the first round to moves around these pose nodes (default: all). Batched
    moves are chosen on estimated gains; the search stops once :data:`STALL_ROUNDS` rounds stop
    paying (moves undoing each other, or only unsafe ones left) instead of cycling until the
    deadline."""
    n = tour.n
    active = np.arange(n) if active is None else np.asarray(active, dtype=np.int64)
    best, stalled = tour.motion_s(), 0
    while len(active) and time.monotonic() < deadline:
        cost = tour.motion_s()
        stalled = stalled + 1 if cost >= best - _EPS else 0
        best = min(best, cost)
        if stalled >= STALL_ROUNDS:
            break
        moves = _candidate_moves(tour, nbr, active)
        chosen = _non_overlapping(moves, n, max_batch)
        if not len(chosen):
            break
        unsafe = _unsafe_moves(tour, moves, chosen)
        touched = _apply(tour, moves, chosen, unsafe)
        if not touched:
            if unsafe:
                continue  # forbidden edges are now known; recompute
            break
        touched_a = np.unique(np.array(touched, dtype=np.int64))
        active = touched_a[touched_a < n]


# ---------------------------------------------------------------------------- driver
def solve(problem: Problem, time_budget_s: float = 5.0, rounds: int = 3) -> Ordering:
    """A short motion order: nearest neighbour, then local search and configuration choice
    alternately, within ``time_budget_s`` of host time for the search."""
    n = problem.n
    if n == 0:
        return Ordering(np.zeros(0, np.int64), np.zeros(0, np.int64), 0.0)
    deadline = time.monotonic() + time_budget_s
    order, choice = nearest_neighbour(problem)
    tour = _Tour(problem, order, choice)
    forbidden_cfg: set[tuple[int, int, int, int]] = set()
    previous = np.inf
    for _ in range(rounds):
        local_search(tour, _neighbours(tour, 8), deadline)
        order = tour.t[1:-1].copy()
        for _ in range(3):  # configuration choice, avoiding the unsafe moves it finds
            tour.set_choice(best_configurations(problem, order, forbidden_cfg))
            bad = _unsafe_positions(tour)
            if not len(bad):
                break
            t = tour.t
            for p in bad:
                a, b = t[p], t[p + 1]
                if a < n and b < n:
                    forbidden_cfg.add((int(a), int(tour.choice[a]), int(b), int(tour.choice[b])))
        cost = tour.motion_s()
        if cost >= previous - 1e-9 or time.monotonic() >= deadline:
            break
        previous = cost
    # Repair: moves found unsafe are charged PENALTY_S, so a search around them removes them;
    # failing that, a 2-opt move reconnecting the unsafe edge to any position of the tour.
    nbr = _neighbours(tour, 8)
    for _ in range(5):
        bad = _unsafe_positions(tour)
        if not len(bad):
            break
        t = tour.t
        around = np.concatenate([t[np.clip(bad + d, 0, n + 1)] for d in (-1, 0, 1, 2)])
        local_search(tour, nbr, time.monotonic() + 1.0, active=np.unique(around[around < n]))
        for p in _unsafe_positions(tour):
            _repair_edge(tour, int(p))
    order = tour.t[1:-1].copy()
    return Ordering(order, tour.choice.copy(), tour.motion_s(), len(_unsafe_positions(tour)))


def _repair_edge(tour: _Tour, p: int, tries: int = 32) -> bool:
    """Replace the unsafe edge at position ``p`` by the best safe 2-opt move with any other
    edge of the tour; True when one was applied."""
    n, t = tour.n, tour.t
    e = tour.edge_costs()
    other = np.arange(n + 1)
    i = np.minimum(other, p)
    j = np.maximum(other, p)
    keep = j >= i + 2
    i, j = i[keep], j[keep]
    if not len(i):
        return False
    gain = e[i] + e[j] - tour.w(t[i], t[j]) - tour.w(t[i + 1], t[j + 1])
    for m in np.argsort(-gain)[:tries]:
        if gain[m] <= _EPS:
            break
        a = np.array([t[i[m]], t[i[m] + 1]])
        b = np.array([t[j[m]], t[j[m] + 1]])
        if tour.check_transits(a, b).all():
            t[i[m] + 1:j[m] + 1] = t[i[m] + 1:j[m] + 1][::-1].copy()
            tour.pos[t] = np.arange(n + 2)
            return True
    return False


def _unsafe_positions(tour: _Tour) -> np.ndarray:
    """Positions p whose move t[p] → t[p+1] fails the transit check."""
    if tour.p.transit_ok is None:
        return np.zeros(0, np.int64)
    t = tour.t
    a, b = t[:-1], t[1:]
    ok = tour.check_transits(a, b)
    return np.flatnonzero(~ok)


def path_motion_s(problem: Problem, order: np.ndarray, choice: np.ndarray) -> float:
    """Motion time (s) of visiting the poses in ``order`` with configurations ``choice``."""
    return _Tour(problem, np.asarray(order), np.asarray(choice)).motion_s()


# ---------------------------------------------------------------------------- lower bound
def _nodes(problem: Problem) -> tuple[np.ndarray, np.ndarray]:
    """Configurations (M, K, J) of the poses, the start and (if fixed) the finish."""
    extra = [problem.start] + ([problem.finish] if problem.finish is not None else [])
    kk = problem.configs.shape[1]
    ends = np.full((len(extra), kk, problem.configs.shape[2]), np.nan)
    ends[:, 0] = np.array(extra)
    pts = np.concatenate([problem.configs, ends])
    valid = ~np.any(np.isnan(pts), axis=-1)
    return pts, valid


def dense_costs(problem: Problem, block_elems: int = 2_000_000) -> np.ndarray:
    """Symmetric matrix of cheapest move times between every pair of nodes (poses, start,
    finish), seconds — rounded down, so that it never overstates a move (single precision
    with a relative margin of 1e-6)."""
    pts, valid = _nodes(problem)
    m = len(pts)
    node_of, slot_of = np.nonzero(valid)  # grouped by node
    flat = pts[node_of, slot_of].astype(np.float32)
    starts = np.searchsorted(node_of, np.arange(m))
    w = np.empty((m, m))
    per_node = max(len(flat) / max(m, 1), 1.0)
    r0 = 0
    while r0 < m:  # blocks of whole nodes against themselves and every later node
        lo = starts[r0]
        rows = max(1, int(block_elems / max(len(flat) - lo, 1) / per_node))
        r1 = min(m, r0 + rows)
        hi = starts[r1] if r1 < m else len(flat)
        c = problem.cost(flat[lo:hi, None, :], flat[None, lo:, :])
        c = np.minimum.reduceat(c, starts[r0:] - lo, axis=1)
        block = np.minimum.reduceat(c, starts[r0:r1] - lo, axis=0).astype(np.float64)
        w[r0:r1, r0:] = block
        w[r0:, r0:r1] = block.T
        r0 = r1
    return w * (1.0 - 1e-6)


def _prim(w: np.ndarray) -> tuple[float, np.ndarray]:
    """Weight and node degrees of a minimum spanning tree of the dense graph ``w``."""
    m = len(w)
    in_tree = np.zeros(m, dtype=bool)
    dist = w[0].copy()
    parent = np.zeros(m, dtype=np.int64)
    in_tree[0] = True
    dist[0] = np.inf
    deg = np.zeros(m, dtype=np.int64)
    total = 0.0
    for _ in range(m - 1):
        v = int(np.argmin(dist))
        total += dist[v]
        deg[v] += 1
        deg[parent[v]] += 1
        in_tree[v] = True
        closer = w[v] < dist
        closer &= ~in_tree
        dist[closer] = w[v][closer]
        parent[closer] = v
        dist[v] = np.inf
    return total, deg


def held_karp_bound(problem: Problem, upper_s: float, time_budget_s: float = 2.0,
                    iterations: int = 200) -> float:
    """Held–Karp bound on the motion time of any path from the start through every pose.

    The path plus a zero-cost dummy node joined to the start (and to the finish, or to the
    free end) is a tour; every tour's cost is at least the Lagrangian 1-tree value
    ``L(π) = MST(w + π_i + π_j) + dummy edges − 2 Σ π``, maximised by subgradient steps.
    ``upper_s`` (a known path's cost) sets the step size.
    """
    n = problem.n
    w = dense_costs(problem)
    m = len(w)
    s = n  # the start node; the finish (if any) is n + 1
    fixed_end = problem.finish is not None
    pi = np.zeros(m)
    best = -np.inf
    lam = 2.0
    stall = 0
    deadline = time.monotonic() + time_budget_s
    for _ in range(iterations):
        wp = w + pi[:, None] + pi[None, :]
        np.fill_diagonal(wp, np.inf)
        tree, deg = _prim(wp)
        # dummy node: edges to the start and to the finish or the cheapest free end
        if fixed_end:
            dummy = pi[s] + pi[n + 1]
            deg[s] += 1
            deg[n + 1] += 1
        else:
            others = pi.copy()
            others[s] = np.inf
            v = int(np.argmin(others))
            dummy = pi[s] + pi[v]
            deg[s] += 1
            deg[v] += 1
        value = tree + dummy - 2.0 * pi.sum()
        if value > best + 1e-12:
            best, stall = value, 0
        else:
            stall += 1
            if stall >= 5:
                lam, stall = lam / 2.0, 0
        g = deg - 2.0
        norm = float(g @ g)
        if norm == 0 or lam < 1e-4 or time.monotonic() > deadline:
            break
        pi += lam * max(upper_s - value, 1e-9) / norm * g
    return max(float(best), 0.0)


def nearest_move_bound(problem: Problem, k: int = 16) -> float:
    """Sum over poses of the cheapest move into each from any other node, seconds.

    Weaker than Held–Karp but needs no dense matrix: neighbours come from a k-d tree on
    the scaled joints, and a search is accepted only when ``problem.reach`` proves that no
    configuration outside it could be cheaper; otherwise that configuration is compared with
    every other one.
    """
    from scipy.spatial import cKDTree

    n = problem.n
    pose_of, slot_of = np.nonzero(problem.valid)
    flat = problem.configs[pose_of, slot_of]
    sources = np.vstack([flat, problem.start[None]])
    src_pose = np.concatenate([pose_of, [-1]])
    scale = problem.scale
    tree = cKDTree(np.nan_to_num(sources * scale))
    kq = min(k, len(sources))
    dist, idx = tree.query(np.nan_to_num(flat * scale), k=kq, p=np.inf)
    dist, idx = dist.reshape(len(flat), kq), idx.reshape(len(flat), kq)
    cost = problem.cost(sources[idx], flat[:, None, :])
    cost = np.where(src_pose[idx] == pose_of[:, None], np.inf, cost)
    best = cost.min(axis=1)
    certified = np.zeros(len(flat), dtype=bool)
    if problem.reach is not None:
        width = problem.reach(np.where(np.isfinite(best), best, 0.0))
        scaled = np.where(scale > 0, width * scale, 0.0)
        radius = scaled.max(axis=1)
        certified = np.isfinite(best) & ((kq == len(sources)) | (radius < dist[:, -1]))
    for r0 in range(0, len(flat), 64):
        rows = np.arange(r0, min(r0 + 64, len(flat)))
        rows = rows[~certified[rows]]
        if not len(rows):
            continue
        c = problem.cost(sources[None, :, :], flat[rows, None, :])
        c = np.where(src_pose[None, :] == pose_of[rows, None], np.inf, c)
        best[rows] = c.min(axis=1)
    per_pose = np.full(n, np.inf)
    np.minimum.at(per_pose, pose_of, best)
    return float(per_pose.sum())


def lower_bound(problem: Problem, upper_s: float, time_budget_s: float = 2.0) -> float:
    """A lower bound (s) on the motion time of any order: Held–Karp for up to
    :data:`DENSE_MAX` poses, otherwise :func:`nearest_move_bound`."""
    if problem.n == 0:
        return 0.0
    if problem.n <= DENSE_MAX:
        return held_karp_bound(problem, upper_s, time_budget_s)
    return nearest_move_bound(problem)
