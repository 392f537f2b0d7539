"""Pieces of a stand-in ``gphoto2`` module (libgphoto2's Python API) shared by the tests that
drive :class:`drivers.gphoto2.GPhoto2Camera` without a camera."""

from __future__ import annotations

import types


class StandInError(Exception):
    """``gphoto2.GPhoto2Error``: carries libgphoto2's error code."""

    def __init__(self, code: int) -> None:
        super().__init__(f"code {code}")
        self.code = code


class Choice:
    """A radio/menu config widget (shutter speed, ISO, ...)."""

    def __init__(self, choices: list[str], value: str) -> None:
        self.choices, self.value = choices, value

    def count_choices(self) -> int:
        return len(self.choices)

    def get_choice(self, i: int) -> str:
        return self.choices[i]

    def set_value(self, v: str) -> None:
        assert v in self.choices, f"{v!r} is not one of the camera's choices"
        self.value = v

    def get_value(self) -> str:
        return self.value


class Config:
    """A camera configuration tree, flattened to named widgets."""

    def __init__(self, widgets: dict[str, Choice]) -> None:
        self.widgets = widgets

    def get_child_by_name(self, name: str) -> Choice:
        if name not in self.widgets:
            raise StandInError(-2)
        return self.widgets[name]


def stand_in_module(camera_class: type) -> types.ModuleType:
    """A ``gphoto2`` module whose ``Camera`` is ``camera_class``."""
    gp = types.ModuleType("gphoto2")
    gp.GPhoto2Error = StandInError
    gp.GP_ERROR_MODEL_NOT_FOUND = -105
    gp.GP_CAPTURE_IMAGE = 0
    gp.GP_FILE_TYPE_NORMAL = 1
    gp.Camera = camera_class
    return gp
