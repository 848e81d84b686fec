"""The Foxglove layout for hydroplant logs and live streams, generated in code with ``foxglove.layouts``.

One 3D panel (the machine: ``/hydroplant/scene`` bodies on ``/tf``, and the hydraulic
cylinders of ``/hydroplant/scene/cylinders``) beside three plots: the cylinder pressures in
bar (``p_cap_bar``, ``p_rod_bar`` of each ``/hydroplant/cylinders/<name>``), the valve
commands (``/hydroplant/valves/<name>.command``, −1..1) and the frame budget of a paced run
(``/hydroplant/frame.budget_pct`` against a line at 100 %, see :mod:`sim.live.frame_topic`).
All plots follow the last 10 s.

The layout of the shipped excavator ships with the package (``hydroplant-layout.json`` next
to this module, :func:`shipped_layout_path`); :func:`layout_json` writes one for any scene's
names (needs ``foxglove-sdk``, the extra ``live``).  Load it in Foxglove with *Layouts →
Import from file*; a scene with other names shows empty series for the names it lacks.

Example
-------
::

    text = layout_json(["boom_cyl", "stick_cyl"], ["boom_valve", "stick_valve"])
    Path("my-layout.json").write_text(text)
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from sim.io.foxglove_scene import CYLINDER_TOPIC
from sim.live.frame_topic import FRAME_TOPIC

SHIPPED_LAYOUT = "hydroplant-layout.json"
EXCAVATOR_CYLINDERS = ("boom_cyl", "stick_cyl", "bucket_cyl")
EXCAVATOR_VALVES = ("boom_valve", "stick_valve", "bucket_valve", "swing_valve")
WINDOW_S = 10.0  # plots follow the last WINDOW_S seconds


def shipped_layout_path() -> Path:
    """The layout file shipped with the package (the excavator's names)."""
    return Path(__file__).with_name(SHIPPED_LAYOUT)


def layout_json(cylinders: Sequence[str], valves: Sequence[str]) -> str:
    """The layout (JSON text) for a scene with these cylinder and valve names."""
    try:
        import foxglove.layouts as fl
    except ImportError as error:  # pragma: no cover - the optional extra
        raise ImportError("generating a Foxglove layout needs foxglove-sdk: pip install 'hydroplant[live]'") from error

    visible = fl.BaseRendererSceneUpdateTopicSettings(visible=True)
    machine = fl.ThreeDeePanel(title="Machine", config=fl.ThreeDeeConfig(
        fixed_frame="world", follow_tf="world", follow_mode="follow-none",
        topics={"/hydroplant/scene": visible, CYLINDER_TOPIC: visible}))
    pressure = [fl.PlotSeries(value=f"/hydroplant/cylinders/{name}.{field}", label=f"{name} {side}")
                for name in cylinders for field, side in (("p_cap_bar", "cap"), ("p_rod_bar", "rod"))]
    pressures = fl.PlotPanel(title="Cylinder pressures [bar]", config=fl.PlotConfig(
        paths=pressure, following_view_width=WINDOW_S, min_y_value=0.0, show_legend=True))
    commands = fl.PlotPanel(title="Valve commands [-]", config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=f"/hydroplant/valves/{name}.command", label=name) for name in valves],
        following_view_width=WINDOW_S, min_y_value=-1.05, max_y_value=1.05, show_legend=True))
    budget = fl.PlotPanel(title="Frame budget [%]", config=fl.PlotConfig(
        paths=[fl.PlotSeries(value=f"{FRAME_TOPIC}.budget_pct", label="physics / frame"),
               fl.PlotSeries(value="100", label="whole frame")],
        following_view_width=WINDOW_S, min_y_value=0.0, show_legend=True))
    plots = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=2, content=pressures), fl.SplitItem(proportion=1, content=commands),
        fl.SplitItem(proportion=1, content=budget)])
    layout = fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=3, content=machine), fl.SplitItem(proportion=2, content=plots)]))
    return layout.to_json()


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m sim.live.layout OUT``: write the excavator's layout to the file OUT (the shipped file is
    ``sim/live/hydroplant-layout.json``)."""
    import sys

    args = list(sys.argv[1:] if argv is None else argv)
    if len(args) != 1:
        print("usage: python -m sim.live.layout OUT.json", file=sys.stderr)
        return 2
    out = Path(args[0])
    out.write_text(layout_json(EXCAVATOR_CYLINDERS, EXCAVATOR_VALVES) + "\n")
    print(out)
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())


__all__ = ["EXCAVATOR_CYLINDERS", "EXCAVATOR_VALVES", "layout_json", "main", "shipped_layout_path"]
