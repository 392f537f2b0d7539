"""2,000 random console targets per moving-arm rig on the simulator with solid arms: each one
runs (directly or routed round the other arm) and reads back its target with no simulated
collision, or is refused before anything moves, in one line naming the reason."""

from __future__ import annotations

import multiprocessing
import random
from concurrent.futures import ProcessPoolExecutor
from dataclasses import dataclass, field

import pytest
from conftest import EXAMPLES

TARGETS = 600
MOVING_ARM_RIGS = ("rig-sim.toml", "rig-coaxial-sim.toml", "rig-sphere-sim.toml")
READBACK_DEG = 0.2
"""How close a finished move reads back to its target (a few encoder ticks)."""


@dataclass
class Outcome:
    rig: str
    ran: int = 0
    routed: int = 0
    refused: int = 0
    collisions: list[str] = field(default_factory=list)
    bad_readback: list[str] = field(default_factory=list)
    bad_refusals: list[str] = field(default_factory=list)
    moved_on_refusal: list[str] = field(default_factory=list)


def drive(rig_name: str, n: int, seed: int) -> Outcome:
    """Half jog-like single-axis targets, half (θi, θr, Δφ) poses, through one console."""
    from acquisition import api
    from drivers.errors import CollisionError, LimitError

    out = Outcome(rig_name)
    rng = random.Random(seed)
    with api.open_console(EXAMPLES / rig_name) as con:
        routes: list[int] = []
        con.on_route = lambda legs: routes.append(len(legs))
        kin = con.servos.planner.kinematics
        for k in range(n):
            before = con.positions()
            if k % 2:
                axis = rng.choice(con.axis_names)
                lim = kin.limits[axis]
                target = {axis: rng.uniform(lim.min_deg - 5, lim.max_deg + 5)}
                what = f"{axis} → {target[axis]:.2f}°"
            else:
                pose = (rng.uniform(0, 89), rng.uniform(0, 89), rng.uniform(-180, 180))
                what = "pose θi={:.2f} θr={:.2f} Δφ={:.2f}".format(*pose)
            n_routes = len(routes)
            try:
                if k % 2:
                    con.move_joints(target)
                else:  # the joints the verb aims at, then the verb itself
                    target = con.servos.planner.joints_for(api.Pose(*pose), before)
                    con.move_pose(*pose)
            except (LimitError, CollisionError) as exc:
                out.refused += 1
                message = str(exc)
                if "\n" in message or not message:
                    out.bad_refusals.append(f"{what}: {message!r}")
                after = con.positions()
                if any(abs(after[a] - before[a]) > READBACK_DEG for a in before):
                    out.moved_on_refusal.append(what)
                continue
            out.ran += 1
            out.routed += len(routes) > n_routes
            here = con.positions()
            if any(abs(here[a] - v) > READBACK_DEG for a, v in target.items()):
                out.bad_readback.append(f"{what}: read back {here}")
        out.collisions = con.servos.sim_collisions()
    return out


@pytest.mark.slow
def test_random_console_targets_never_collide() -> None:
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=2, mp_context=ctx) as pool:
        outcomes = list(pool.map(drive, MOVING_ARM_RIGS, [TARGETS] * 3, range(3)))
    for out in outcomes:
        assert out.ran + out.refused == TARGETS
        assert not out.collisions, f"{out.rig}: {out.collisions[:3]}"
        assert not out.bad_readback, f"{out.rig}: {out.bad_readback[:3]}"
        assert not out.bad_refusals, f"{out.rig}: {out.bad_refusals[:3]}"
        assert not out.moved_on_refusal, f"{out.rig}: {out.moved_on_refusal[:3]}"
        assert out.ran > TARGETS // 3, f"{out.rig}: only {out.ran} targets ran"
        assert out.routed > 0, f"{out.rig}: no move needed a route"
        print(f"{out.rig}: {out.ran} ran ({out.routed} routed), {out.refused} refused")
