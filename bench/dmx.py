"""DMX light switching over the simulated widget on a real pty (host clock).

Measures the request/reply round trip and the time per OLAT state of a 156-light dome
(``set_state`` until the state is confirmed on), next to the timing bound the controller
waits for, computed in the same run: one output period + one frame + USB margin.
"""

from __future__ import annotations

import time

import numpy as np

from acquisition.config.dome import geodesic_directions
from drivers.dmx import DmxWidget
from drivers.lights import LightController, pack_fixtures
from simulators.dmx import SimDmxWidget


def bench_dmx() -> dict[str, dict[str, float | str]]:
    """Round trip, OLAT state time and a full 156-light OLAT sweep against the simulator."""
    fixtures = pack_fixtures(geodesic_directions(156))  # one intensity channel each
    with SimDmxWidget() as sim:
        with DmxWidget(sim.path) as widget:
            trips = []
            for _ in range(50):
                t0 = time.perf_counter()
                widget.get_parameters()
                trips.append(time.perf_counter() - t0)
            bound_s = widget.ready_at(0.0, len(fixtures))  # 156 one-channel fixtures
        with LightController.open({1: sim.path}, fixtures) as lights:  # type: ignore[dict-item]
            per_state = []
            t_sweep = time.perf_counter()
            for i in range(len(fixtures)):
                t0 = time.perf_counter()
                lights.olat(i)
                per_state.append(time.perf_counter() - t0)
            sweep_s = time.perf_counter() - t_sweep
        errors = sum(sim.sim_errors().values())
    if errors:
        raise RuntimeError(f"simulator saw {errors} malformed frames during the benchmark")
    return {
        "dmx_round_trip_median": {"value": float(np.median(trips)) * 1e3, "unit": "ms"},
        "dmx_olat_state_median": {"value": float(np.median(per_state)) * 1e3, "unit": "ms"},
        "dmx_olat_state_bound": {"value": bound_s * 1e3, "unit": "ms"},
        "dmx_olat_sweep_156": {"value": sweep_s, "unit": "s"},
    }


if __name__ == "__main__":
    for key, fig in bench_dmx().items():
        print(f"{key}: {fig['value']:.4g} {fig['unit']}")
