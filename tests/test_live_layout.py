"""The shipped Foxglove layout: generated in code from the excavator's names, and every series and 3D topic it shows
is a topic and field of a real excavator log (the frame budget: of the frame topic a paced run writes)."""

from __future__ import annotations

import json

from conftest import MODELS
from sim.io.foxglove_scene import CYLINDER_TOPIC
from sim.io.mcap_log import read_log
from sim.io.scenario import load_scenario
from sim.io.scene import load_scene
from sim.live.frame_topic import FRAME_FIELDS, FRAME_TOPIC
from sim.live.figures import scene_figure
from sim.live.layout import EXCAVATOR_CYLINDERS, EXCAVATOR_VALVES, layout_json, shipped_layout_path
from sim.run.runner import run


def panels(node):
    if node.get("type") == "panel":
        yield node
    for item in node.get("items", []):
        yield from panels(item["content"])


def test_shipped_layout_is_the_generated_one_and_names_real_fields(tmp_path):
    shipped = shipped_layout_path().read_text()
    assert json.loads(shipped) == json.loads(layout_json(EXCAVATOR_CYLINDERS, EXCAVATOR_VALVES))
    scene = load_scene(load_scenario(MODELS / "excavator" / "dig.scenario.toml"))
    net = scene.network
    assert set(EXCAVATOR_CYLINDERS) == {net.actuator_names[a] for a in net.cylinder_actuator}
    assert set(EXCAVATOR_VALVES) == set(net.valve_names)

    result = run(MODELS / "excavator" / "dig.scenario.toml", out=tmp_path / "dig.mcap", overrides={"duration": 0.05})
    log = read_log(result.log_path)
    found = {p["panelType"]: p for p in panels(json.loads(shipped)["content"])}
    assert set(found) == {"ThreeDee", "Plot"}
    three_d = next(p for p in panels(json.loads(shipped)["content"]) if p["panelType"] == "ThreeDee")
    assert set(three_d["config"]["topics"]) == {"/hydroplant/scene", CYLINDER_TOPIC} <= set(log.topics)
    series = [s["value"] for p in panels(json.loads(shipped)["content"]) if p["panelType"] == "Plot"
              for s in p["config"]["paths"]]
    assert any(s.endswith(".p_cap_bar") for s in series) and any(s.endswith(".command") for s in series)
    for value in series:
        if value.replace(".", "", 1).isdigit():  # a reference line
            continue
        topic, field = value.rsplit(".", 1)
        if topic == FRAME_TOPIC:
            assert field in FRAME_FIELDS
        else:
            assert field in log.topic(topic).fields, value

    # the documentation's scene picture is drawn from these messages
    png = scene_figure(result.log_path, tmp_path / "scene.png", int(log.topic("/tf").log_time[-1]))
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
