"""Servo bus round trips: median sync read of 3 and 8 servos (ms), with and without wire time.

The driver (`ServoBus.read_positions`: one SYNC_READ through the real dynamixel_sdk, replies
collected by ID) talks to a `SimServoBus` in the same process with Return Delay Time 0, the
low-latency setting a real bus should use too.

* ``servo_sync_read_N_wire_ms``: the simulator charges the bytes their time on the wire at
  57600 baud (the default): what a real bus takes, less the USB adapter's latency.
* ``servo_sync_read_N_pty_ms``: wire time off: the pty's and the code's own overhead.
* ``servo_sync_read_3_wire_ideal_ms``: the same sync read's bytes at 57600 baud computed
  here from the Protocol 2.0 packet sizes (14 + n instruction bytes, 15 per reply), the
  baseline the wire figure should approach.
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


BAUD = 57600


def _sync_reads_ms(wire_time: bool | str, rounds: int) -> tuple[float, float]:
    ids = list(range(1, 9))
    with SimServoBus(ids, baud=BAUD, wire_time=wire_time) as sim, \
            ServoBus(sim.port, BAUD, name="bench") as bus:
        bus.set_return_delay(ids, 0)
        return (_median_ms(lambda: bus.read_positions(ids[:3]), rounds),
                _median_ms(lambda: bus.read_positions(ids), rounds))


def bench_servo() -> dict[str, dict[str, float | str]]:
    """Median sync-read round trips of 3 and of 8 servos, wire time on and off (ms)."""
    pty3, pty8 = _sync_reads_ms(False, _ROUNDS)
    wire3, wire8 = _sync_reads_ms("host", 60)
    ideal3 = ((14 + 3) + 3 * (11 + 4)) * 10.0 / BAUD * 1000.0
    return {
        "servo_sync_read_3_wire_ms": {"value": wire3, "unit": "ms"},
        "servo_sync_read_8_wire_ms": {"value": wire8, "unit": "ms"},
        "servo_sync_read_3_wire_ideal_ms": {"value": ideal3, "unit": "ms"},
        "servo_sync_read_3_pty_ms": {"value": pty3, "unit": "ms"},
        "servo_sync_read_8_pty_ms": {"value": pty8, "unit": "ms"},
    }


if __name__ == "__main__":
    for name, fig in bench_servo().items():
        print(f"{name}: {fig['value']:.3f} {fig['unit']}")
