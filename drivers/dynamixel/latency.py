"""Check the USB-serial adapter's latency timer (FTDI chips: U2D2, USB2Dynamixel).

An FTDI adapter holds received bytes up to ``latency_timer`` ms (default 16) before handing them
to the host, so every status packet waits that long: a sync read at 16 ms instead of < 1 ms.
Set it to 1 ms::

    echo 1 | sudo tee /sys/bus/usb-serial/devices/ttyUSB0/latency_timer

or permanently with a udev rule, e.g. in ``/etc/udev/rules.d/99-dynamixel.rules``::

    ACTION=="add", SUBSYSTEM=="usb-serial", DRIVER=="ftdi_sio", ATTR{latency_timer}="1"

Also set each servo's Return Delay Time to 0 (:meth:`ServoBus.set_return_delay`).
"""

from __future__ import annotations

import os
from pathlib import Path

SYSFS_USB_SERIAL = Path("/sys/bus/usb-serial/devices")


def latency_timer_ms(port: str, sysfs: Path = SYSFS_USB_SERIAL) -> int | None:
    """The adapter's latency timer (ms), or None when the port has none (pty, ACM, absent)."""
    tty = os.path.basename(os.path.realpath(port))
    try:
        return int((sysfs / tty / "latency_timer").read_text().strip())
    except (OSError, ValueError):
        return None


def latency_warning(port: str, sysfs: Path = SYSFS_USB_SERIAL) -> str | None:
    """A one-line warning if ``port``'s latency timer is above 1 ms, else None."""
    value = latency_timer_ms(port, sysfs)
    if value is None or value <= 1:
        return None
    tty = os.path.basename(os.path.realpath(port))
    return (
        f"servo port {port}: USB latency timer is {value} ms, so every servo reply waits up to "
        f"{value} ms; set it to 1 ms with `echo 1 | sudo tee {sysfs / tty / 'latency_timer'}`"
    )
