"""The test-wide collision referee (a pytest hook the suite's conftest loads).

After each phase of each test — setup (fixtures of every scope set up for it: a module- or
session-scoped fixture's capture counts for the first test that needs it), call, teardown —
it drains the process-wide record of the simulated arms' contacts
(:func:`simulators.dynamixel.drain_collisions`: every simulated bus of the process, whoever
started it; live ones are stepped to the present first) and fails that phase of the test if
any contact happened in it, unless the test is marked ``@pytest.mark.collides`` (it drives the
arms into each other on purpose). Simulators in child processes are not in this record: tests
that run gonio in a subprocess check what it reports (the session journal's ``simulated
collision`` events, the simulator's warnings on stderr).
"""

from __future__ import annotations

from collections.abc import Generator
from typing import Any

import pytest

SIM_COLLISION_EVENT = "simulated collision"
"""How a session journal records a contact of the simulated arms (``gonio info`` shows it)."""
SIM_COLLISION_LOG = "arms touched"
"""How the simulator words a contact in its warning (a child process's stderr shows it)."""


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[Any]
                              ) -> Generator[None, Any, None]:
    outcome = yield
    from simulators.dynamixel import drain_collisions

    hits = drain_collisions()
    if not hits or item.get_closest_marker("collides"):
        return
    report = outcome.get_result()
    message = (f"the simulated arms collided during {call.when} of {item.nodeid} (fixtures of "
               "every scope count; mark the test @pytest.mark.collides if it means to): "
               + "; ".join(map(str, hits)))
    if report.failed:
        report.sections.append(("simulated collisions", message))
    else:
        report.outcome = "failed"
        report.longrepr = message
