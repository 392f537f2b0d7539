"""Servo bus round trips on the simulator's pty: median sync read of 3 and 8 servos (ms).

The driver (`ServoBus.read_positions`: one SYNC_READ through the real dynamixel_sdk, replies
collected by ID) talks to a `SimServoBus` in the same process with Return Delay Time 0, the
low-latency setting a real bus should use too. On hardware add the adapter's latency and the
wire time (at 57600 baud ≈ 0.17 ms per byte, 15 bytes per reply).
"""

from __future__ import annotations

import statistics
import time

from drivers.dynamixel import ServoBus
from simulators.dynamixel import SimServoBus

_ROUNDS = 400


def _median_ms(fn, rounds: int = _ROUNDS) -> float:
    for _ in range(20):  # warm up
        fn()
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times) * 1000.0


def bench_servo() -> dict[str, dict[str, float | str]]:
    """Median sync-read round trip of 3 and of 8 servos on the simulator's pty (ms)."""
    ids = list(range(1, 9))
    with SimServoBus(ids) as sim, ServoBus(sim.port, 57600, name="bench") as bus:
        bus.set_return_delay(ids, 0)
        three = _median_ms(lambda: bus.read_positions(ids[:3]))
        eight = _median_ms(lambda: bus.read_positions(ids))
    return {
        "servo_sync_read_3_ms": {"value": three, "unit": "ms"},
        "servo_sync_read_8_ms": {"value": eight, "unit": "ms"},
    }


if __name__ == "__main__":
    for name, fig in bench_servo().items():
        print(f"{name}: {fig['value']:.3f} {fig['unit']}")
