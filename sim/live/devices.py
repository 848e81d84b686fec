"""Operator devices as command sources: a gamepad through pygame's joystick API, and the keyboard of the viewer.

Both give the device axes named in :mod:`sim.live.protocol`, each in [−1, 1]:

=========== ================================================================================
``left_x``   left stick, +1 = pushed right
``left_y``   left stick, +1 = pushed forward (away from the operator)
``right_x``  right stick, +1 = pushed right
``right_y``  right stick, +1 = pushed forward
``l2, r2``   triggers, 0 = released, +1 = pulled fully
=========== ================================================================================

A mapping (ISO or SAE pattern, dead band, expo) turns the axes into valve commands; the
sources here report the device as it is, without a dead band.

**Gamepad** (:class:`GamepadSource`, optional extra ``gamepad``: ``pygame``).  SDL reports
axis *motion events*; the source keeps every axis at the value of its last event (an axis
never moved reads its rest value: 0, a trigger released) and drops them all to rest when the
device goes away.  The events come from an injectable callable, so the source runs without
pygame (tests, or another event library); :meth:`GamepadSource.open` wires it to pygame.
SDL's stick y axes point down (pushed forward is −1): the source negates them.  Triggers
read −1 at rest through SDL's joystick API: the source maps them to [0, 1].

**Keyboard** (:class:`KeyboardSource`): the MuJoCo viewer's ``key_callback`` gets one call
per key press (and per auto-repeat while a key is held), never a release, so each press
moves its axis one ``step`` and holding a key ramps it; numpad 5 or 0 returns every axis to 0.
Every letter is already a viewer shortcut (render and visualisation flags), so the default
keys are the editing block for the left stick and the numpad for the right one:

=================  ===========  =================  ===========
key                axis         key                axis
=================  ===========  =================  ===========
Home / End         left_y ±     numpad 8 / 2       right_y ±
Page Down / Del    left_x ±     numpad 6 / 4       right_x ±
=================  ===========  =================  ===========

Example
-------
>>> events = [Motion(axis=1, value=-1.0), Motion(axis=5, value=1.0)]
>>> pad = GamepadSource(lambda: events)
>>> pad.poll(0.0)["left_y"], pad.poll(0.0)["r2"]
(1.0, 1.0)
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any

AXES = ("left_x", "left_y", "right_x", "right_y", "l2", "r2")
STICKS = AXES[:4]
TRIGGERS = AXES[4:]

# SDL's event type numbers (SDL_events.h), which pygame's JOYAXISMOTION, JOYDEVICEADDED, JOYDEVICEREMOVED equal
JOYAXISMOTION = 0x600
JOYDEVICEADDED = 0x605
JOYDEVICEREMOVED = 0x606


@dataclass(frozen=True)
class Motion:
    """A pygame-like joystick axis motion event (for injected event sources and tests)."""

    axis: int
    value: float
    instance_id: int = 0
    type: int = JOYAXISMOTION


@dataclass(frozen=True)
class Removed:
    """A pygame-like device-removed event."""

    instance_id: int = 0
    type: int = JOYDEVICEREMOVED


@dataclass(frozen=True)
class GamepadLayout:
    """Which SDL joystick axis is which named axis, and which are negated.

    The default is SDL's game-controller order (``LEFTX, LEFTY, RIGHTX, RIGHTY,
    TRIGGERLEFT, TRIGGERRIGHT``); :data:`XBOX_LINUX` is an Xbox pad through the Linux joystick
    driver (triggers between the sticks).
    """

    axes: Mapping[int, str] = field(default_factory=lambda: {0: "left_x", 1: "left_y", 2: "right_x", 3: "right_y",
                                                             4: "l2", 5: "r2"})
    """SDL axis index → axis name (one of :data:`AXES`)."""
    inverted: tuple[str, ...] = ("left_y", "right_y")
    """Axes whose SDL sign is opposite to this module's (SDL's y axes point down)."""

    def __post_init__(self) -> None:
        unknown = set(self.axes.values()) - set(AXES)
        if unknown:
            raise ValueError(f"gamepad layout: unknown axis names {sorted(unknown)}; allowed {list(AXES)}")


XBOX_LINUX = GamepadLayout(axes={0: "left_x", 1: "left_y", 2: "l2", 3: "right_x", 4: "right_y", 5: "r2"})


def _clamp(value: float) -> float:
    return max(-1.0, min(1.0, float(value)))


class GamepadSource:
    """:class:`~sim.live.protocol.CommandSource` of a gamepad's axes, kept from its axis motion events.

    Parameters
    ----------
    events : callable
        Returns the events since the last call (pygame's ``pygame.event.get`` filtered to
        joystick events, or an injected source); each has ``type``, and ``axis``, ``value``
        (and ``instance_id``) for a motion.  Motion of an axis the layout does not name is
        ignored.
    layout : GamepadLayout, optional
        Axis numbering.
    instance_id : int or None, optional
        Only events of this joystick (``None``: any).
    on_close : callable, optional
        Called once by :meth:`close` (releases the device).
    """

    def __init__(self, events: Callable[[], Iterable[Any]], *, layout: GamepadLayout | None = None,
                 instance_id: int | None = None, on_close: Callable[[], None] | None = None):
        self._events = events
        self.layout = layout or GamepadLayout()
        self.instance_id = instance_id
        self._on_close = on_close
        self._values = dict.fromkeys(AXES, 0.0)
        self.connected = True
        """False after the device was removed (every axis then reads its rest value)."""

    @classmethod
    def open(cls, index: int = 0, *, layout: GamepadLayout | None = None) -> GamepadSource:
        """The source of joystick ``index`` through pygame (SDL); ``RuntimeError`` when there is none.

        Needs the optional extra ``gamepad`` (pygame ≥ 2.5).  pygame's event queue is read
        with ``pygame.event.get`` for the joystick event types only, so other windows' events
        stay queued for them.
        """
        try:
            import pygame
        except ImportError as error:
            raise ImportError("the gamepad needs pygame: pip install 'hydroplant[gamepad]'") from error
        pygame.init()
        pygame.joystick.init()
        count = pygame.joystick.get_count()
        if not 0 <= index < count:
            raise RuntimeError(f"gamepad {index}: {count} joystick(s) found (connect one, or choose 0..{count - 1})")
        joystick = pygame.joystick.Joystick(index)
        kinds = [pygame.JOYAXISMOTION, pygame.JOYDEVICEADDED, pygame.JOYDEVICEREMOVED]
        return cls(lambda: pygame.event.get(kinds), layout=layout, instance_id=joystick.get_instance_id(),
                   on_close=joystick.quit)

    def _apply(self, event: Any) -> None:
        kind = getattr(event, "type", None)
        if self.instance_id is not None and getattr(event, "instance_id", self.instance_id) != self.instance_id:
            return
        if kind == JOYDEVICEREMOVED:
            self._values = dict.fromkeys(AXES, 0.0)
            self.connected = False
        elif kind == JOYDEVICEADDED:
            self.connected = True
        elif kind == JOYAXISMOTION:
            name = self.layout.axes.get(int(event.axis))
            if name is None:
                return
            value = _clamp(event.value)
            if name in self.layout.inverted:
                value = -value
            if name in TRIGGERS:
                value = 0.5 * (value + 1.0)  # SDL's joystick trigger: −1 released .. +1 pulled
            self._values[name] = value

    def poll(self, t: float) -> dict[str, float]:
        """Apply the events since the last poll; every axis's latest value."""
        for event in self._events():
            self._apply(event)
        return dict(self._values)

    def close(self) -> None:
        """Release the device (idempotent)."""
        if self._on_close is not None:
            hook, self._on_close = self._on_close, None
            hook()


# GLFW key codes (GLFW_KEY_*), what mujoco.viewer's key_callback receives
KEY_DELETE, KEY_PAGE_DOWN, KEY_HOME, KEY_END = 261, 267, 268, 269
KEY_KP = tuple(range(320, 330))  # numpad 0..9
NEUTRAL_KEYS = (KEY_KP[5], KEY_KP[0])
DEFAULT_KEYS = {KEY_HOME: ("left_y", 1.0), KEY_END: ("left_y", -1.0), KEY_PAGE_DOWN: ("left_x", 1.0),
                KEY_DELETE: ("left_x", -1.0), KEY_KP[8]: ("right_y", 1.0), KEY_KP[2]: ("right_y", -1.0),
                KEY_KP[6]: ("right_x", 1.0), KEY_KP[4]: ("right_x", -1.0)}


class KeyboardSource:
    """:class:`~sim.live.protocol.CommandSource` of key presses in the MuJoCo viewer (pass :meth:`key` as its
    ``key_callback``); see the module docstring for the keys.

    Parameters
    ----------
    step : float, optional
        Axis change per press (and per auto-repeat) [-], in (0, 1].
    keys : mapping, optional
        GLFW key code → (axis, direction ±1).
    neutral : sequence of int, optional
        GLFW key codes that set every axis to 0.
    """

    def __init__(self, step: float = 0.1, keys: Mapping[int, tuple[str, float]] | None = None,
                 neutral: Iterable[int] = NEUTRAL_KEYS):
        if not 0.0 < step <= 1.0:
            raise ValueError(f"keyboard step must be in (0, 1], got {step!r}")
        self.step = float(step)
        self.keys = dict(DEFAULT_KEYS if keys is None else keys)
        unknown = {axis for axis, _ in self.keys.values()} - set(AXES)
        if unknown:
            raise ValueError(f"keyboard keys: unknown axis names {sorted(unknown)}; allowed {list(AXES)}")
        self.neutral = frozenset(int(k) for k in neutral)
        self._lock = threading.Lock()  # the viewer calls key() from its own thread
        self._values = dict.fromkeys(AXES, 0.0)

    def key(self, keycode: int) -> None:
        """One key press (the viewer's ``key_callback``): move its axis one step, or (a neutral key) every axis
        to 0."""
        with self._lock:
            if keycode in self.neutral:
                self._values = dict.fromkeys(AXES, 0.0)
                return
            binding = self.keys.get(int(keycode))
            if binding is not None:
                axis, direction = binding
                self._values[axis] = _clamp(round(self._values[axis] + direction * self.step, 12))

    def poll(self, t: float) -> dict[str, float]:
        """Every axis's value."""
        with self._lock:
            return dict(self._values)

    def close(self) -> None:
        """Nothing to release."""


__all__ = ["AXES", "DEFAULT_KEYS", "NEUTRAL_KEYS", "GamepadLayout", "GamepadSource", "KeyboardSource", "Motion", "Removed",
           "XBOX_LINUX"]
