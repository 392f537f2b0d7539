"""Light fixtures on DMX universes: channel maps, commanded state, timing confirmation.

A :class:`Fixture` is one light (an LED of a dome) with a DMX address, a channel map
(role → offset from its start channel) and a direction in the sample frame. A
:class:`LightController` turns a state ``{fixture name: level or (r, g, b)}`` into one DMX
universe per widget, sends only the universes that changed, and keeps what it commanded.

Confirmation is by timing, not readback: a DMX USB Pro cannot report what it outputs, and DMX
fixtures do not answer. A state counts as on at the latest :meth:`drivers.dmx.DmxWidget.ready_at`
of the universes it changed (one output period + one frame on the wire + USB margin + settle
time). :meth:`LightController.covers` tells whether an exposure interval lay entirely under the
current, settled state. A fixture that is unpowered, mis-addressed or broken is not detected
here; that needs a photometric check (a dark frame and an all-on frame).

A thermal duty-cycle limit per LED (largest on-fraction over a sliding window) is checked
before every command: the state is refused (:class:`drivers.errors.LimitError`) or, with
``DutyPolicy.WAIT``, all lights go off until the LEDs concerned have cooled enough.
A light counts as fully on at any non-zero level (conservative). The check runs when a state is
commanded; pass the expected on-time as ``hold_s`` so a long exposure is checked in advance.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from enum import Enum
from types import MappingProxyType
from typing import Protocol

import numpy as np

from drivers.dmx import MAX_CHANNELS, MIN_CHANNELS, Clock, DmxWidget, MonotonicClock
from drivers.errors import ConfigError, LimitError

Level = float | tuple[float, float, float]
"""A fixture's level: 0–1 (white), or an (r, g, b) triple of 0–1 values."""

DRIVEN_ROLES = ("intensity", "r", "g", "b", "w")
"""Channel roles the controller sets; any other role holds its value from ``Fixture.fixed``."""


class UniverseOutput(Protocol):
    """What the controller needs from a widget (:class:`drivers.dmx.DmxWidget` fits)."""

    @property
    def port(self) -> str: ...

    def send_universe(self, levels: bytes) -> float: ...

    def ready_at(self, sent_at_s: float, n_channels: int | None = None) -> float: ...

    def close(self) -> None: ...


@dataclass(frozen=True)
class Fixture:
    """One light on a DMX universe.

    Parameters
    ----------
    name:
        Unique name (e.g. ``"L017"``).
    universe:
        Universe number (a key of the controller's widgets).
    start_channel:
        DMX start address, 1–512.
    channels:
        Role → offset from ``start_channel`` (0 = the start channel itself). Driven roles:
        ``intensity``, ``r``, ``g``, ``b``, ``w``; other roles (mode, strobe…) hold ``fixed``.
    direction:
        Unit vector from the sample towards the light, in the sample frame (normal +z).
    fixed:
        Role → DMX value (0–255) always sent for non-driven roles.
    """

    name: str
    universe: int
    start_channel: int
    channels: Mapping[str, int]
    direction: tuple[float, float, float]
    fixed: Mapping[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        where = f"fixture {self.name!r}"
        if not self.name:
            raise ConfigError("a fixture has an empty name; give every light a unique name")
        if not self.channels:
            raise ConfigError(f"{where} has no channels; map at least 'intensity' to an offset")
        for role, off in self.channels.items():
            if not isinstance(off, int) or off < 0:
                raise ConfigError(f"{where}: channel offset {role}={off!r} must be an int ≥ 0")
        last = self.start_channel + max(self.channels.values())
        if self.start_channel < 1 or last > MAX_CHANNELS:
            raise ConfigError(
                f"{where}: channels {self.start_channel}–{last} fall outside DMX 1–512; "
                "fix its start_channel or move it to another universe"
            )
        for role, value in self.fixed.items():
            if role not in self.channels or role in DRIVEN_ROLES or not 0 <= value <= 255:
                raise ConfigError(
                    f"{where}: fixed {role}={value!r} must name a non-driven channel, value 0–255"
                )
        d = np.asarray(self.direction, dtype=float)
        norm = float(np.linalg.norm(d)) if d.shape == (3,) else 0.0
        if not (norm > 0 and math.isfinite(norm)):
            raise ConfigError(f"{where}: direction {self.direction!r} is not a non-zero 3-vector")
        object.__setattr__(self, "direction", tuple(float(x) for x in d / norm))
        object.__setattr__(self, "channels", MappingProxyType(dict(self.channels)))
        object.__setattr__(self, "fixed", MappingProxyType(dict(self.fixed)))

    @property
    def addresses(self) -> dict[str, int]:
        """Role → absolute DMX channel (1-based)."""
        return {role: self.start_channel + off for role, off in self.channels.items()}

    @property
    def has_colour(self) -> bool:
        """Whether the fixture has r, g and b channels."""
        return all(c in self.channels for c in "rgb")

    def dmx_values(self, level: Level) -> dict[int, int]:
        """Absolute channel → DMX value for ``level`` (ValueError if it does not fit)."""
        addr = self.addresses
        out = {addr[role]: int(v) for role, v in self.fixed.items()}
        driven = {role: 0.0 for role in DRIVEN_ROLES if role in addr}
        if isinstance(level, tuple | list | np.ndarray):
            rgb = tuple(float(x) for x in level)
            if len(rgb) != 3 or not self.has_colour:
                raise ValueError(
                    f"fixture {self.name!r} takes a scalar level (channels: "
                    f"{', '.join(self.channels)}), got {level!r}"
                )
            _check_unit(self.name, rgb)
            if any(rgb):
                driven.update(r=rgb[0], g=rgb[1], b=rgb[2])
                if "intensity" in driven:
                    driven["intensity"] = 1.0
        else:
            v = float(level)
            _check_unit(self.name, (v,))
            if v > 0:
                if "intensity" in driven:
                    driven = {role: 1.0 for role in driven}
                    driven["intensity"] = v
                else:
                    driven = {role: v for role in driven}
        for role, v in driven.items():
            out[addr[role]] = round(v * 255)
        return out


def _check_unit(name: str, values: Iterable[float]) -> None:
    for v in values:
        if not 0.0 <= v <= 1.0:
            raise ValueError(f"level {v} for fixture {name!r} is outside 0–1; nothing was sent")


def fixture_from_config(entry: Mapping[str, object], where: str = "fixture") -> Fixture:
    """A :class:`Fixture` from rig-file data (keys: name, universe, start_channel, channels,
    direction, optional fixed); ConfigError names the missing or bad field."""
    required = ("name", "universe", "start_channel", "channels", "direction")
    missing = [k for k in required if k not in entry]
    if missing:
        raise ConfigError(f"{where} lacks {', '.join(missing)}; add it to the rig file")
    unknown = set(entry) - {*required, "fixed"}
    if unknown:
        raise ConfigError(f"{where} has unknown keys {sorted(unknown)}; remove or rename them")
    try:
        return Fixture(
            name=str(entry["name"]),
            universe=int(entry["universe"]),  # type: ignore[call-overload]
            start_channel=int(entry["start_channel"]),  # type: ignore[call-overload]
            channels=dict(entry["channels"]),  # type: ignore[call-overload]
            direction=tuple(entry["direction"]),  # type: ignore[arg-type]
            fixed=dict(entry.get("fixed", {})),  # type: ignore[call-overload]
        )
    except ConfigError as exc:
        raise ConfigError(f"{where}: {exc}") from None
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where} is malformed ({exc}); check its field types") from None


def pack_fixtures(
    directions: np.ndarray | Sequence[Sequence[float]],
    *,
    channels: Mapping[str, int] | None = None,
    fixed: Mapping[str, int] | None = None,
    first_universe: int = 1,
    name_format: str = "L{index:03d}",
) -> list[Fixture]:
    """Fixtures for ``directions``, addressed one after another, spilling into new universes.

    Each fixture occupies ``max(offset) + 1`` channels (``channels`` defaults to a single
    intensity channel); a fixture never straddles two universes.
    """
    chans = dict(channels or {"intensity": 0})
    footprint = max(chans.values()) + 1
    per_universe = MAX_CHANNELS // footprint
    out = []
    for i, d in enumerate(np.asarray(directions, dtype=float)):
        u, slot = divmod(i, per_universe)
        out.append(
            Fixture(
                name=name_format.format(index=i),
                universe=first_universe + u,
                start_channel=1 + slot * footprint,
                channels=chans,
                direction=tuple(d),  # type: ignore[arg-type]
                fixed=dict(fixed or {}),
            )
        )
    return out


class DutyPolicy(Enum):
    """What to do when a state would exceed an LED's duty-cycle limit."""

    RAISE = "raise"
    """Refuse the state with a LimitError saying how long to wait."""
    WAIT = "wait"
    """Turn every light off, wait until the LEDs concerned have cooled, then proceed."""


@dataclass(frozen=True)
class DutyCycleLimit:
    """Largest fraction of ``window_s`` an LED may be on (thermal protection)."""

    max_on_fraction: float
    window_s: float
    policy: DutyPolicy = DutyPolicy.RAISE

    def __post_init__(self) -> None:
        if not (0 < self.max_on_fraction <= 1 and self.window_s > 0):
            raise ConfigError(
                f"duty-cycle limit {self.max_on_fraction} over {self.window_s} s: the fraction "
                "must be in (0, 1] and the window > 0 s"
            )


class _OnTimes:
    """On-intervals of one LED, pruned to the duty window."""

    def __init__(self) -> None:
        self.intervals: list[list[float]] = []  # [start, end]; end = inf while on

    @property
    def is_on(self) -> bool:
        return bool(self.intervals) and self.intervals[-1][1] == math.inf

    def switch(self, on: bool, t: float) -> None:
        if on and not self.is_on:
            self.intervals.append([t, math.inf])
        elif not on and self.is_on:
            self.intervals[-1][1] = t

    def on_time(self, t0: float, t1: float, off_at: float | None = None) -> float:
        """On-time within [t0, t1], optionally treating a current on-interval as ending at
        ``off_at``."""
        total = 0.0
        for a, b in self.intervals:
            if b == math.inf:
                b = off_at if off_at is not None else t1
            total += max(0.0, min(b, t1) - max(a, t0))
        return total

    def prune(self, before: float) -> None:
        self.intervals = [iv for iv in self.intervals if iv[1] > before]


@dataclass(frozen=True)
class LightState:
    """A commanded light state and when it is surely on.

    Attributes
    ----------
    levels:
        Fixture name → commanded level (every fixture; 0.0 = off).
    sent_at_s:
        Clock time the last changed universe was handed to its widget (s).
    ready_at_s:
        Clock time from which the state is on and settled (s).
    """

    levels: Mapping[str, Level]
    sent_at_s: float
    ready_at_s: float

    @property
    def lit(self) -> tuple[str, ...]:
        """Names of the fixtures that are on."""
        return tuple(n for n, v in self.levels.items() if _is_on(v))


def _norm_level(level: Level | Sequence[float] | np.ndarray) -> Level:
    if np.ndim(level) == 0:
        return float(level)  # type: ignore[arg-type]
    values = tuple(float(x) for x in np.ravel(level))
    return values  # type: ignore[return-value]  # a wrong length is refused in dmx_values


def _is_on(level: Level) -> bool:
    return any(level) if isinstance(level, tuple) else level > 0


class LightController:
    """Commands light states over one widget per universe and confirms them by timing.

    Parameters
    ----------
    widgets:
        Universe number → widget (e.g. :class:`drivers.dmx.DmxWidget`).
    fixtures:
        The lights, in index order (``olat(i)`` lights ``fixtures[i]``).
    duty_limit:
        Thermal duty-cycle limit applied to every LED; None for no limit.
    clock:
        Time source (s); must be the widgets' clock.
    owns_widgets:
        Close the widgets in :meth:`close`.

    Raises
    ------
    ConfigError
        On duplicate names, a universe without a widget, or two fixtures sharing a channel.
    """

    def __init__(
        self,
        widgets: Mapping[int, UniverseOutput],
        fixtures: Sequence[Fixture],
        *,
        duty_limit: DutyCycleLimit | None = None,
        clock: Clock | None = None,
        owns_widgets: bool = False,
    ) -> None:
        self._widgets = dict(widgets)
        self._fixtures = list(fixtures)
        self._by_name: dict[str, Fixture] = {}
        self._duty = duty_limit
        self._clock: Clock = clock if clock is not None else MonotonicClock()
        self._owns = owns_widgets
        owner: dict[tuple[int, int], str] = {}
        self._size: dict[int, int] = dict.fromkeys(self._widgets, MIN_CHANNELS)
        for f in self._fixtures:
            if f.name in self._by_name:
                raise ConfigError(f"two fixtures are named {f.name!r}; names must be unique")
            if f.universe not in self._widgets:
                raise ConfigError(
                    f"fixture {f.name!r} is on universe {f.universe}, which has no widget; "
                    f"add a port for it (universes with ports: {sorted(self._widgets)})"
                )
            for ch in f.addresses.values():
                other = owner.setdefault((f.universe, ch), f.name)
                if other != f.name:
                    raise ConfigError(
                        f"fixtures {other!r} and {f.name!r} both use channel {ch} of universe "
                        f"{f.universe}; fix their start_channel"
                    )
                self._size[f.universe] = max(self._size[f.universe], ch)
            self._by_name[f.name] = f
        self._on = {f.name: _OnTimes() for f in self._fixtures}
        self._sent: dict[int, bytes] = {}
        self._state: LightState | None = None

    @classmethod
    def open(
        cls,
        ports: Mapping[int, str],
        fixtures: Sequence[Fixture],
        *,
        settle_s: float = 0.0,
        duty_limit: DutyCycleLimit | None = None,
        clock: Clock | None = None,
    ) -> LightController:
        """Open one :class:`DmxWidget` per universe (universe → port) and own them."""
        widgets: dict[int, DmxWidget] = {}
        try:
            for universe, port in ports.items():
                widgets[universe] = DmxWidget(port, settle_s=settle_s, clock=clock)
        except BaseException:
            for w in widgets.values():
                w.close()
            raise
        return cls(widgets, fixtures, duty_limit=duty_limit, clock=clock, owns_widgets=True)

    # -- readback ------------------------------------------------------------------------------

    @property
    def fixtures(self) -> tuple[Fixture, ...]:
        """The lights, in index order."""
        return tuple(self._fixtures)

    @property
    def state(self) -> LightState | None:
        """The last commanded state (None before the first command)."""
        return self._state

    def universes(self) -> dict[int, bytes]:
        """Universe → levels last sent to its widget (the commanded readback)."""
        return dict(self._sent)

    def covers(self, start_s: float, end_s: float) -> bool:
        """Whether an exposure over [start_s, end_s] lay entirely under the current state.

        True iff the current state was settled by ``start_s`` and ``end_s`` is not in the
        future (no later command can have changed it, since every command goes through here).
        """
        return (
            self._state is not None
            and self._state.ready_at_s <= start_s <= end_s <= self._clock.now()
        )

    def wait_ready(self) -> LightState:
        """Block until the current state is on and settled; return it."""
        if self._state is None:
            raise RuntimeError("no light state has been commanded yet")
        self._clock.sleep(self._state.ready_at_s - self._clock.now())
        return self._state

    def duty_fraction(self, name: str, at_s: float | None = None) -> float:
        """On-fraction of fixture ``name`` over the duty window ending at ``at_s`` (default now)."""
        t = self._clock.now() if at_s is None else at_s
        window = self._duty.window_s if self._duty else 60.0
        return self._on[self._fixture(name).name].on_time(t - window, t) / window

    # -- commands ------------------------------------------------------------------------------

    def set_state(
        self, levels: Mapping[str, Level], *, hold_s: float = 0.0, wait: bool = True
    ) -> LightState:
        """Light the named fixtures at their levels, all others off.

        Parameters
        ----------
        levels:
            Fixture name → 0–1 level or (r, g, b); unnamed fixtures go off.
        hold_s:
            How long the state will stay on (s), for the duty-cycle check.
        wait:
            Block until the state is on and settled (default; never expose before).

        Raises
        ------
        LimitError
            A level outside 0–1, or a duty-cycle limit would be exceeded (nothing was sent).
        ConfigError
            An unknown fixture name.
        CommunicationError
            A widget is gone; the state may be partly applied.
        """
        full = {f.name: 0.0 for f in self._fixtures}
        for name, level in levels.items():
            full[self._fixture(name).name] = _norm_level(level)
        frames = self._render(full)
        if self._duty is not None:
            self._enforce_duty(full, hold_s)
        return self._send(full, frames, wait)

    def olat(
        self, index: int, level: Level = 1.0, *, hold_s: float = 0.0, wait: bool = True
    ) -> LightState:
        """One light at a time: ``fixtures[index]`` at ``level``, all others off."""
        if not 0 <= index < len(self._fixtures):
            raise LimitError(
                f"light index {index} is outside 0–{len(self._fixtures) - 1}; nothing was sent"
            )
        return self.set_state({self._fixtures[index].name: level}, hold_s=hold_s, wait=wait)

    def all_on(
        self, level: Level = 1.0, *, hold_s: float = 0.0, wait: bool = True
    ) -> LightState:
        """Every light at ``level``."""
        return self.set_state(
            {f.name: level for f in self._fixtures}, hold_s=hold_s, wait=wait
        )

    def all_off(self, *, wait: bool = True) -> LightState:
        """Every light off (a dark frame's state)."""
        return self.set_state({}, wait=wait)

    def close(self) -> None:
        """Turn all lights off (best effort) and close owned widgets."""
        try:
            # best effort: cleanup must not mask the error that got us here
            with contextlib.suppress(Exception):
                if self._state is not None and self._state.lit:
                    self.all_off(wait=False)
        finally:
            if self._owns:
                for w in self._widgets.values():
                    w.close()

    def __enter__(self) -> LightController:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals -----------------------------------------------------------------------------

    def _fixture(self, name: str) -> Fixture:
        try:
            return self._by_name[name]
        except KeyError:
            raise ConfigError(
                f"no fixture named {name!r}; known: {', '.join(list(self._by_name)[:5])}…"
            ) from None

    def _render(self, full: Mapping[str, Level]) -> dict[int, bytes]:
        frames = {u: bytearray(n) for u, n in self._size.items()}
        for name, level in full.items():
            f = self._by_name[name]
            try:
                values = f.dmx_values(level)
            except ValueError as exc:
                raise LimitError(str(exc)) from None
            for ch, v in values.items():
                frames[f.universe][ch - 1] = v
        return {u: bytes(b) for u, b in frames.items()}

    def _enforce_duty(self, full: Mapping[str, Level], hold_s: float) -> None:
        assert self._duty is not None
        lim = self._duty
        budget = lim.max_on_fraction * lim.window_s
        if hold_s > budget:
            raise LimitError(
                f"holding a light on for {hold_s:g} s exceeds its duty budget of {budget:g} s "
                f"per {lim.window_s:g} s; shorten the exposure or raise the limit"
            )
        waits = self._cooldowns(full, hold_s)
        if not waits:
            return
        name, wait_s = max(waits.items(), key=lambda kv: kv[1])
        if lim.policy is DutyPolicy.RAISE:
            raise LimitError(
                f"light {name!r} was on {self.duty_fraction(name):.0%} of the last "
                f"{lim.window_s:g} s (limit {lim.max_on_fraction:.0%}); wait {wait_s:.1f} s "
                "or use the WAIT duty policy; nothing was sent"
            )
        if self._state is not None and self._state.lit:
            self.all_off(wait=False)
        waits = self._cooldowns(full, hold_s)  # from when the lights really went off
        self._clock.sleep(max(waits.values(), default=0.0))

    def _cooldowns(self, full: Mapping[str, Level], hold_s: float) -> dict[str, float]:
        """Fixture → wait (s) before it may go on, for the fixtures that must wait."""
        now = self._clock.now()
        waits = {n: self._cooldown_s(n, now, hold_s) for n, v in full.items() if _is_on(v)}
        return {n: w for n, w in waits.items() if w > 0}

    def _cooldown_s(self, name: str, now: float, hold_s: float) -> float:
        """Shortest wait (s) after which lighting ``name`` for ``hold_s`` keeps within budget,
        with the light off while waiting (0 if it may go on now)."""
        assert self._duty is not None
        window, budget = self._duty.window_s, self._duty.max_on_fraction * self._duty.window_s
        on = self._on[name]

        def used(w: float) -> float:
            t = now + w
            return on.on_time(t + hold_s - window, t, off_at=now if w > 0 else None)

        if used(0.0) + hold_s <= budget:
            return 0.0
        lo, hi = 0.0, window
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            lo, hi = (lo, mid) if used(mid) + hold_s <= budget else (mid, hi)
        return hi

    def _send(self, full: dict[str, Level], frames: dict[int, bytes], wait: bool) -> LightState:
        sent_at: float | None = None
        ready_at = self._state.ready_at_s if self._state is not None else -math.inf
        for universe, frame in frames.items():
            if self._sent.get(universe) == frame:
                continue
            widget = self._widgets[universe]
            t = widget.send_universe(frame)
            self._sent[universe] = frame
            sent_at = t
            ready_at = max(ready_at, widget.ready_at(t, len(frame)))
        if sent_at is None:  # nothing changed: the current state stands
            sent_at = self._state.sent_at_s if self._state is not None else self._clock.now()
            ready_at = self._state.ready_at_s if self._state is not None else sent_at
        for name, level in full.items():
            self._on[name].switch(_is_on(level), sent_at)
        if self._duty is not None:
            for on in self._on.values():
                on.prune(self._clock.now() - self._duty.window_s - 1.0)
        self._state = LightState(MappingProxyType(dict(full)), sent_at, ready_at)
        if wait:
            self.wait_ready()
        return self._state
