"""Operator devices: the gamepad source fed by injected (pygame-like) events, and the viewer's keyboard source."""

from __future__ import annotations

import pytest

from sim.live.devices import (AXES, DEFAULT_KEYS, JOYAXISMOTION, JOYDEVICEADDED, JOYDEVICEREMOVED, NEUTRAL_KEYS,
                              XBOX_LINUX, GamepadLayout, GamepadSource, KeyboardSource, Motion, Removed)
from sim.live.protocol import CommandSource


class Queue:
    """An injected event source: what was put since the last call."""

    def __init__(self):
        self.pending = []

    def put(self, *events):
        self.pending.extend(events)

    def __call__(self):
        out, self.pending = self.pending, []
        return out


def test_gamepad_keeps_each_axis_at_its_last_motion_event():
    queue = Queue()
    pad = GamepadSource(queue)
    assert isinstance(pad, CommandSource)
    assert pad.poll(0.0) == dict.fromkeys(AXES, 0.0)  # never moved: at rest
    queue.put(Motion(0, 0.25), Motion(1, -0.5), Motion(1, -0.75), Motion(3, 0.4))
    first = pad.poll(0.0)
    # the last event of an axis wins; SDL's y axes point down: pushed forward (−0.75) reads +0.75
    assert first == {"left_x": 0.25, "left_y": 0.75, "right_x": 0.0, "right_y": -0.4, "l2": 0.0, "r2": 0.0}
    # no new event: every axis holds (dead reckoning of the motion events, not a decay)
    assert pad.poll(0.1) == first
    queue.put(Motion(0, 0.0), Motion(2, -1.0))
    second = pad.poll(0.2)
    assert second["left_x"] == 0.0 and second["right_x"] == -1.0 and second["left_y"] == 0.75


def test_gamepad_triggers_map_to_zero_one_and_values_are_clamped():
    queue = Queue()
    pad = GamepadSource(queue)
    queue.put(Motion(4, -1.0), Motion(5, 1.0))
    values = pad.poll(0.0)
    assert (values["l2"], values["r2"]) == (0.0, 1.0)  # released, pulled fully
    queue.put(Motion(5, 0.0), Motion(0, 1.7), Motion(9, 0.5))  # half pulled; out of range; an unnamed axis
    values = pad.poll(0.0)
    assert values["r2"] == 0.5 and values["left_x"] == 1.0 and set(values) == set(AXES)


def test_gamepad_other_layout_other_device_and_removal():
    queue = Queue()
    pad = GamepadSource(queue, layout=XBOX_LINUX, instance_id=3)
    queue.put(Motion(2, 1.0, instance_id=3), Motion(3, 0.5, instance_id=3), Motion(0, 1.0, instance_id=4))
    values = pad.poll(0.0)
    assert values["l2"] == 1.0 and values["right_x"] == 0.5 and values["left_x"] == 0.0  # device 4 is not ours
    queue.put(Removed(instance_id=4))
    assert pad.connected and pad.poll(0.0)["l2"] == 1.0
    queue.put(Removed(instance_id=3))
    assert pad.poll(0.0) == dict.fromkeys(AXES, 0.0) and not pad.connected  # unplugged: everything to rest


def test_gamepad_layout_and_close():
    with pytest.raises(ValueError, match="unknown axis names"):
        GamepadLayout(axes={0: "throttle"})
    released = []
    pad = GamepadSource(lambda: [], on_close=lambda: released.append(1))
    pad.close()
    pad.close()
    assert released == [1]


def test_gamepad_through_pygames_event_queue(monkeypatch):
    """The same source reading pygame's real event queue (SDL's dummy video driver, no device): posted axis events
    come out as axes, and the event numbers are SDL's."""
    pygame = pytest.importorskip("pygame")  # the optional extra `gamepad`
    monkeypatch.setenv("SDL_VIDEODRIVER", "dummy")
    pygame.display.init()
    try:
        assert (pygame.JOYAXISMOTION, pygame.JOYDEVICEADDED, pygame.JOYDEVICEREMOVED) == (
            JOYAXISMOTION, JOYDEVICEADDED, JOYDEVICEREMOVED)
        kinds = [pygame.JOYAXISMOTION, pygame.JOYDEVICEREMOVED]
        pad = GamepadSource(lambda: pygame.event.get(kinds), instance_id=0)
        pygame.event.post(pygame.event.Event(pygame.JOYAXISMOTION, joy=0, instance_id=0, axis=3, value=-0.6))
        pygame.event.post(pygame.event.Event(pygame.JOYAXISMOTION, joy=0, instance_id=0, axis=0, value=0.3))
        values = pad.poll(0.0)
        assert values["right_y"] == pytest.approx(0.6) and values["left_x"] == pytest.approx(0.3)
        pygame.joystick.init()
        if pygame.joystick.get_count() == 0:
            with pytest.raises(RuntimeError, match="0 joystick"):
                GamepadSource.open(0)
    finally:
        pygame.display.quit()


def test_keyboard_ramps_per_press_and_neutral_centres():
    import mujoco

    keys = KeyboardSource(step=0.25)
    assert isinstance(keys, CommandSource)
    # none of the default keys is a viewer shortcut (every letter is one)
    shortcuts = {row[2] for table in (mujoco.mjVISSTRING, mujoco.mjRNDSTRING) for row in table if row[2]}
    assert all(len(s) == 1 for s in shortcuts) and not {ord(s) for s in shortcuts} & (set(DEFAULT_KEYS) | set(NEUTRAL_KEYS))
    home, end, kp = 268, 269, list(range(320, 330))
    for _ in range(3):
        keys.key(home)
    keys.key(kp[4])
    keys.key(ord("Q"))  # not bound: nothing
    values = keys.poll(0.0)
    assert values["left_y"] == 0.75 and values["right_x"] == -0.25 and values["left_x"] == 0.0
    for _ in range(10):  # held (auto-repeat): ramps to the end and stays there
        keys.key(home)
        keys.key(kp[2])
    values = keys.poll(0.0)
    assert values["left_y"] == 1.0 and values["right_y"] == -1.0
    keys.key(end)
    assert keys.poll(0.0)["left_y"] == 0.75
    keys.key(kp[5])  # numpad 5: neutral
    assert keys.poll(0.0) == dict.fromkeys(AXES, 0.0)
    with pytest.raises(ValueError, match="step"):
        KeyboardSource(step=0.0)
