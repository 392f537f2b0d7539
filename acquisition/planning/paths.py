"""Swept paths of moves: a conservative continuous clearance check, the sync-write rule, and
routes round the other arm.

A move is a sync write: every axis starts together and follows its own trapezoid. Along it
the arms' capsules must keep ``clearance_m`` apart. The check is *continuous*, not sampled:
every joint of these rigs turns about an axis through the sample centre, so between two path
points whose joints differ by Δθ_j (rad) no point of an arm moves more than
``reach_m · Σ_j |Δθ_j|`` (``reach_m`` the capsules' outer ends, added for both arms), and the
gap (m) can drop at most that much: an interval whose end gaps g₀, g₁ satisfy
``(g₀ + g₁ − reach · Σ|Δθ|) / 2 ≥ 0`` is clear. Intervals that are not proven clear are
halved (up to :data:`MAX_BISECTIONS` times) and anything still unproven counts as a
collision, so a move is accepted only when it is proven safe.

A sync write is a broadcast with no reply, so one servo can miss it and the others move alone
(:func:`axis_subsets`): a move is safe only when every subset of its moving axes, moving alone
from the same start, is safe too.

When the direct move is not safe, :class:`Router` finds via points on a lattice over the
joints that move the arms (Dijkstra on the time model, then shortcuts), each leg safe by the
same rule.
"""

from __future__ import annotations

import itertools
import threading
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import numpy as np

from drivers.errors import CollisionError

MAX_BISECTIONS = 14
"""Halvings of an interval before an unproven one counts as a collision."""
INITIAL_STEP_DEG = 1.0
"""Largest joint travel between the first checked points of a path (deg)."""
MOVING_DEG = 1e-6
"""An axis whose target differs from its start by more than this moves (deg)."""
LATTICE_STEP_DEG = 10.0
"""Spacing of the routing lattice over the arm joints (deg)."""
MEMO_SIZE = 16
"""Single moves whose verdict :meth:`PathChecker.safe` remembers (a move is routed, then
checked again by the guard before it is sent)."""


def axis_subsets(moving: Sequence[int]) -> list[tuple[int, ...]]:
    """Every non-empty subset of the moving axes (indices), the full set first."""
    subsets: list[tuple[int, ...]] = [tuple(moving)]
    for k in range(len(moving) - 1, 0, -1):
        subsets.extend(itertools.combinations(moving, k))
    return subsets


@dataclass(frozen=True)
class PathProblem:
    """Why a move is refused: which moving axes, and where the arms meet."""

    moving: tuple[str, ...]
    """The axes moving in the refused (sub)move."""
    at: dict[str, float]
    """Joints (deg) of the closest approach found."""
    gap_m: float
    """Clearance left there (m, negative: short of the clearance by that much)."""
    partial: bool
    """The problem arises only if some of the axes miss the sync write."""
    others: tuple[str, ...] = ()
    """The move's other moving axes (those that missed the sync write when ``partial``)."""


class PathChecker:
    """Continuous clearance checks of moves for one kinematics.

    Parameters
    ----------
    gap_m:
        ``gap_m(joints (N, J)) -> (N,)``: capsule distance minus radii minus the clearance (m).
    positions:
        ``positions(a, b, t_s)``: joints on the move a → b at time t (the time model's).
    duration_s:
        ``duration_s(a, b)``: the move's duration (s).
    reach_m:
        Largest distance of an arm point from the sample centre (both arms added).
    arm_joints:
        Indices of the joints that move an arm (the others cannot bring arms together).
    """

    def __init__(self, gap_m: Callable[[np.ndarray], np.ndarray],
                 positions: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray],
                 duration_s: Callable[[np.ndarray, np.ndarray], np.ndarray],
                 reach_m: float, arm_joints: Sequence[int]) -> None:
        self.gap_m = gap_m
        self.positions = positions
        self.duration_s = duration_s
        self.reach_m = float(reach_m)
        self.arm_joints = np.asarray(arm_joints, dtype=int)
        self._memo: dict[tuple[bytes, bytes], bool] = {}
        self._memo_lock = threading.Lock()

    # -- one set of moves ---------------------------------------------------------------
    def min_gap(self, a: np.ndarray, b: np.ndarray, floor: np.ndarray | float = 0.0
                ) -> tuple[np.ndarray, np.ndarray]:
        """For the moves a → b (M, J): whether each keeps its gap ≥ ``floor`` (m) along the
        whole path, proven (bool (M,)), and the joints (M, J) of the least gap seen."""
        a = np.asarray(a, dtype=float).reshape(-1, a.shape[-1])
        b = np.asarray(b, dtype=float).reshape(-1, b.shape[-1])
        m = len(a)
        floor = np.broadcast_to(np.asarray(floor, dtype=float), (m,))
        if m == 0:
            return np.ones(0, bool), a.copy()
        travel = np.abs(b - a)[:, self.arm_joints].max(axis=1, initial=0.0)
        n = np.clip(np.ceil(travel / INITIAL_STEP_DEG).astype(np.int64), 1, 2048)
        owner = np.repeat(np.arange(m), n + 1)
        start = np.cumsum(n + 1) - (n + 1)
        frac = (np.arange(len(owner)) - start[owner]) / n[owner]
        dur = self.duration_s(a, b)
        ok = np.ones(m, dtype=bool)
        worst_gap = np.full(m, np.inf)
        worst_at = a.copy()
        # intervals: (owner, f0, f1, joints0, joints1, gap0, gap1)
        pts = self.positions(a[owner], b[owner], frac * dur[owner])
        gaps = self.gap_m(pts)
        self._note(owner, pts, gaps, worst_gap, worst_at)
        ok &= np.bincount(owner[gaps < floor[owner]], minlength=m) == 0
        first = np.ones(len(owner), dtype=bool)
        first[start] = False
        i1 = np.flatnonzero(first)
        i0 = i1 - 1
        iv = (owner[i1], frac[i0], frac[i1], pts[i0], pts[i1], gaps[i0], gaps[i1])
        for _ in range(MAX_BISECTIONS + 1):
            own, f0, f1, p0, p1, g0, g1 = iv
            live = ok[own]
            bound = self._lower_bound(p0, p1, g0, g1)
            open_ = live & (bound < floor[own])
            if not open_.any():
                return ok, worst_at
            own, f0, f1, p0, p1, g0, g1 = (x[open_] for x in (own, f0, f1, p0, p1, g0, g1))
            fm = 0.5 * (f0 + f1)
            pm = self.positions(a[own], b[own], fm * dur[own])
            gm = self.gap_m(pm)
            self._note(own, pm, gm, worst_gap, worst_at)
            ok &= np.bincount(own[gm < floor[own]], minlength=m) == 0
            iv = tuple(np.concatenate(pair) for pair in (
                (own, own), (f0, fm), (fm, f1), (p0, pm), (pm, p1), (g0, gm), (gm, g1)))
        own, f0, f1, p0, p1, g0, g1 = iv
        unproven = ok[own] & (self._lower_bound(p0, p1, g0, g1) < floor[own])
        ok &= np.bincount(own[unproven], minlength=m) == 0
        return ok, worst_at

    def _lower_bound(self, p0: np.ndarray, p1: np.ndarray, g0: np.ndarray, g1: np.ndarray
                     ) -> np.ndarray:
        """Least gap an interval can hold (m): ends g0, g1 and the largest arm displacement."""
        turn = np.radians(np.abs(p1 - p0)[:, self.arm_joints]).sum(axis=1)
        return 0.5 * (g0 + g1 - self.reach_m * turn)

    @staticmethod
    def _note(owner: np.ndarray, pts: np.ndarray, gaps: np.ndarray, worst_gap: np.ndarray,
              worst_at: np.ndarray) -> None:
        """Keep, per move, the joints of the least gap seen so far."""
        order = np.lexsort((gaps, owner))
        first = np.ones(len(order), dtype=bool)
        first[1:] = owner[order][1:] != owner[order][:-1]
        idx = order[first]
        own = owner[idx]
        better = gaps[idx] < worst_gap[own]
        worst_gap[own[better]] = gaps[idx][better]
        worst_at[own[better]] = pts[idx][better]

    # -- the sync-write rule ------------------------------------------------------------
    def move_safe(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Whether each move a → b (M, J) is safe with every subset of its moving axes moving
        alone (a missed sync write); a start already inside the clearance may only move away
        (no point of the path closer than the start)."""
        a = np.atleast_2d(np.asarray(a, dtype=float))
        b = np.atleast_2d(np.asarray(b, dtype=float))
        m, n_joints = a.shape
        if m == 0:
            return np.ones(0, dtype=bool)
        floor = np.minimum(self.gap_m(a), 0.0)
        moving = np.abs(b - a) > MOVING_DEG
        masks = np.array(list(itertools.product((False, True), repeat=n_joints))[1:])
        rows, ends, owners = [], [], []
        for mask in masks:  # every subset of the axes, for the moves that move all of it
            use = np.flatnonzero(~np.any(mask & ~moving, axis=1))
            if len(use):
                rows.append(a[use])
                ends.append(np.where(mask, b[use], a[use]))
                owners.append(use)
        still = np.flatnonzero(~moving.any(axis=1))  # nothing moves: the pose itself
        rows.append(a[still])
        ends.append(a[still])
        owners.append(still)
        own = np.concatenate(owners)
        ok, _ = self.min_gap(np.concatenate(rows), np.concatenate(ends), floor[own])
        return np.bincount(own[~ok], minlength=m) == 0

    def safe(self, a: np.ndarray, b: np.ndarray) -> bool:
        """:meth:`move_safe` of the one move a → b (J,), remembering the last
        :data:`MEMO_SIZE` verdicts."""
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        key = (a.tobytes(), b.tobytes())
        with self._memo_lock:
            known = self._memo.get(key)
        if known is not None:
            return known
        verdict = bool(self.move_safe(a[None], b[None])[0])
        with self._memo_lock:
            self._memo[key] = verdict
            while len(self._memo) > MEMO_SIZE:
                del self._memo[next(iter(self._memo))]
        return verdict

    def problem(self, a: np.ndarray, b: np.ndarray, names: Sequence[str]) -> PathProblem | None:
        """Why the move a → b (J,) is refused, or None when it is safe (one vectorised check
        first; the subsets one by one only to word a refusal)."""
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        moving = [j for j in range(len(a)) if abs(b[j] - a[j]) > MOVING_DEG]
        if not moving or self.safe(a, b):
            return None
        floor = min(float(self.gap_m(a[None])[0]), 0.0)
        for k, sub in enumerate(axis_subsets(moving)):
            end = a.copy()
            end[list(sub)] = b[list(sub)]
            ok, at = self.min_gap(a[None], end[None], floor)
            if not ok[0]:
                return PathProblem(tuple(names[j] for j in sub),
                                   {n: float(v) for n, v in zip(names, at[0], strict=True)},
                                   float(self.gap_m(at)[0]), partial=k > 0,
                                   others=tuple(names[j] for j in moving if j not in sub))
        return None


class Router:
    """Collision-free routes between joint configurations, through via points.

    The lattice spans the arm joints at :data:`LATTICE_STEP_DEG` within the soft limits; its
    nodes (those ``node_ok`` accepts: clear of each other, outside the shadow cone, below the
    maximum elevation) and one-axis edges (each a safe move) are built on first use and kept.
    The route found is shortened where a direct leg (checked with every rule) skips via
    points. Other joints go straight to their targets on the last leg.
    """

    def __init__(self, checker: PathChecker, lo: np.ndarray, hi: np.ndarray,
                 move_s: Callable[[np.ndarray, np.ndarray], np.ndarray],
                 node_ok: Callable[[np.ndarray], np.ndarray]) -> None:
        self.checker = checker
        self.lo, self.hi = np.asarray(lo, float), np.asarray(hi, float)
        self.move_s = move_s
        self.node_ok = node_ok
        self._graph: tuple[np.ndarray, object] | None = None

    def route(self, a: np.ndarray, b: np.ndarray) -> list[np.ndarray] | None:
        """Joints of the legs' ends from a to b (via points, then b), or None when no route
        exists on the lattice. A safe direct move is returned as ``[b]``."""
        a, b = np.asarray(a, float), np.asarray(b, float)
        if self.checker.safe(a, b):
            return [b]
        nodes, graph = self._lattice(a)
        path = self._search(a, b, nodes, graph)
        return None if path is None else self._shortcut([a, *path, b])

    def reachable(self, start: np.ndarray, configs: np.ndarray) -> np.ndarray:
        """Which configurations (N, J) a collision-free route connects with ``start`` (J,):
        those joined, in both directions, to a lattice node of a component ``start`` joins
        (NaN rows are not reachable)."""
        from scipy.sparse.csgraph import connected_components

        configs = np.asarray(configs, float)
        out = np.zeros(len(configs), dtype=bool)
        nodes, graph = self._lattice(np.asarray(start, float))
        if not len(nodes):
            return out
        _, label = connected_components(graph, directed=False)
        home = set(label[self._connect(np.asarray(start, float), nodes, outgoing=True)])
        valid = np.flatnonzero(~np.isnan(configs).any(axis=1))
        if not home or not len(valid):
            return out
        from scipy.spatial import cKDTree

        arm = self.checker.arm_joints
        k = min(6, len(nodes))
        _, near = cKDTree(nodes[:, arm]).query(configs[valid][:, arm], k=k, p=np.inf)
        near = np.asarray(near).reshape(len(valid), k)
        c = np.repeat(configs[valid], k, axis=0)
        ends = c.copy()
        ends[:, arm] = nodes[near.ravel()][:, arm]
        ok, _ = self.checker.min_gap(c, ends)  # a clear path joins it to the node's component
        joined = ok.reshape(-1, k) & np.isin(label[near], list(home))
        out[valid] = joined.any(axis=1)
        return out

    # -- lattice -----------------------------------------------------------------------
    def _lattice(self, template: np.ndarray) -> tuple[np.ndarray, object]:
        if self._graph is None:
            self._graph = self._build(template)
        return self._graph

    def _build(self, template: np.ndarray) -> tuple[np.ndarray, object]:
        from scipy.sparse import coo_matrix

        arm = self.checker.arm_joints
        axes = [np.unique(np.clip(np.append(np.arange(self.lo[j], self.hi[j], LATTICE_STEP_DEG),
                                            self.hi[j]), self.lo[j], self.hi[j])) for j in arm]
        grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, len(arm))
        nodes = np.repeat(template[None], len(grid), axis=0)
        nodes[:, arm] = grid
        keep = self.node_ok(nodes)
        nodes = nodes[keep]
        index = -np.ones([len(x) for x in axes], dtype=np.int64)
        cells = np.stack([np.searchsorted(x, grid[keep, k]) for k, x in enumerate(axes)], -1)
        index[tuple(cells.T)] = np.arange(len(nodes))
        src, dst = [], []
        for k in range(len(arm)):  # one-axis edges: a missed sync write changes nothing, and
            nb = cells.copy()      # the path is the same both ways
            nb[:, k] += 1
            inside = nb[:, k] < index.shape[k]
            j = np.full(len(nodes), -1)
            j[inside] = index[tuple(nb[inside].T)]
            have = j >= 0
            src.append(np.flatnonzero(have))
            dst.append(j[have])
        src, dst = np.concatenate(src), np.concatenate(dst)
        safe = self.checker.move_safe(nodes[src], nodes[dst])
        src, dst = src[safe], dst[safe]
        cost = self.move_s(nodes[src], nodes[dst]) + 1e-6
        n = len(nodes)
        graph = coo_matrix((np.concatenate([cost, cost]),
                            (np.concatenate([src, dst]), np.concatenate([dst, src]))),
                           shape=(n, n)).tocsr()
        return nodes, graph

    def _search(self, a: np.ndarray, b: np.ndarray, nodes: np.ndarray, graph: object
                ) -> list[np.ndarray] | None:
        from scipy.sparse.csgraph import dijkstra

        arm = self.checker.arm_joints
        if not len(nodes):
            return None
        near_a = self._connect(a, nodes, outgoing=True)
        near_b = self._connect(b, nodes, outgoing=False)
        if not len(near_a) or not len(near_b):
            return None
        dist, pred = dijkstra(graph, indices=near_a, return_predecessors=True)
        enter = self.move_s(a[None], nodes[near_a])
        leave = self.move_s(nodes[near_b], b[None])
        total = enter[:, None] + dist[:, near_b] + leave[None, :]
        i, k = np.unravel_index(int(np.argmin(total)), total.shape)
        if not np.isfinite(total[i, k]):
            return None
        chain, node = [], int(near_b[k])
        while node != near_a[i]:
            chain.append(node)
            node = int(pred[i, node])
            if node < 0:
                return None
        chain.append(int(near_a[i]))
        path = []
        for n in reversed(chain):
            p = a.copy()
            p[arm] = nodes[n, arm]
            path.append(p)
        return path

    def _connect(self, x: np.ndarray, nodes: np.ndarray, *, outgoing: bool, k: int = 12
                 ) -> np.ndarray:
        """Up to ``k`` nearest lattice nodes reachable from (or reaching) ``x`` safely."""
        arm = self.checker.arm_joints
        d = np.abs(nodes[:, arm] - x[arm]).max(axis=1)
        near = np.argsort(d)[:k * 4]
        ends = nodes[near].copy()
        ends[:, [j for j in range(len(x)) if j not in set(arm)]] = x[
            [j for j in range(len(x)) if j not in set(arm)]]
        starts = np.repeat(x[None], len(near), axis=0)
        ok = (self.checker.move_safe(starts, ends) if outgoing
              else self.checker.move_safe(ends, starts))
        return near[ok][:k]

    def _shortcut(self, points: list[np.ndarray]) -> list[np.ndarray]:
        """Drop via points where a safe direct leg skips them (greedy, farthest first)."""
        out, i = [], 0
        while i < len(points) - 1:
            j = len(points) - 1
            while j > i + 1 and not self.checker.move_safe(points[i][None], points[j][None])[0]:
                j -= 1
            out.append(points[j])
            i = j
        return out


def route_or_raise(router: Router, a: Mapping[str, float], b: Mapping[str, float],
                   names: Sequence[str], refuse: Callable[[PathProblem | None], str]
                   ) -> list[dict[str, float]]:
    """Legs from ``a`` to ``b`` as joint dicts, or :class:`CollisionError` with the one line
    ``refuse`` words from the direct move's problem when no route exists inside the limits."""
    va = np.array([a[n] for n in names], float)
    vb = np.array([b[n] for n in names], float)
    legs = router.route(va, vb)
    if legs is None:
        raise CollisionError(refuse(router.checker.problem(va, vb, names)))
    return [{n: float(v) for n, v in zip(names, leg, strict=True)} for leg in legs]
