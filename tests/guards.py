"""Stand-in motion guards for driver tests that exercise the bus, not the planner."""

from __future__ import annotations

from collections.abc import Mapping


class RecordingGuard:
    """Allows every move and records what it was asked: ``calls`` holds (start, targets)."""

    def __init__(self) -> None:
        self.calls: list[tuple[dict[str, float], dict[str, float]]] = []

    def check_move(self, start_deg: Mapping[str, float], targets_deg: Mapping[str, float]) -> None:
        self.calls.append((dict(start_deg), dict(targets_deg)))

    @property
    def targets(self) -> list[dict[str, float]]:
        return [t for _, t in self.calls]
