"""Independent check of the ROS 2 CDR topics: Foxglove's own Python decoder (mcap-ros2-support) reads every CDR
message of real run logs to exactly (bit for bit) the values ``read_log`` returns, after a merge and a recovery too."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from conftest import MODELS
from sim.io.mcap_log import (
    FRAME_TRANSFORMS,
    JOINT_STATES,
    cdr_decode,
    cdr_encode,
    flat_schema,
    merge_logs,
    read_log,
    recover,
    ros2msg_type,
)
from sim.run.runner import run
from test_mcap_log import check_message_indexes

# (list field, name field) of the arrays read_log keys by element name
NAMED = {JOINT_STATES.name: ("joints", "name"), FRAME_TRANSFORMS.name: ("transforms", "child_frame_id")}


def _flatten(obj, prefix: str, out: dict, skip: str = "") -> None:
    """mcap_ros2's decoded object as {dotted field: value} (arrays as ``field[i]``), without field ``skip``."""
    for name in type(obj).__slots__:
        if name == skip:
            continue
        value = getattr(obj, name)
        if hasattr(type(value), "__slots__"):
            _flatten(value, f"{prefix}{name}.", out)
        elif isinstance(value, list):
            for i, item in enumerate(value):
                if hasattr(type(item), "__slots__"):
                    _flatten(item, f"{prefix}{name}[{i}].", out)
                else:
                    out[f"{prefix}{name}[{i}]"] = item
        else:
            out[prefix + name] = value


def independent_columns(path, topic: str) -> tuple[list[int], dict[str, list]]:
    """Log times and the columns of every message of ``topic``, decoded by mcap_ros2 alone."""
    decoders = DecoderFactory()
    times, columns = [], {}
    with open(path, "rb") as f:
        for schema, channel, message in make_reader(f).iter_messages(topics=[topic], log_time_order=True):
            assert channel.message_encoding == "cdr" and schema.encoding == "ros2msg"
            decoded = decoders.decoder_for("cdr", schema)(message.data)
            flat: dict = {}
            if schema.name in NAMED:
                list_key, name_key = NAMED[schema.name]
                _flatten(decoded, "", flat, skip=list_key)
                for element in getattr(decoded, list_key):
                    part: dict = {}
                    _flatten(element, "", part)
                    label = part.pop(name_key)
                    flat.update({f"{key}/{label}": value for key, value in part.items()})
            else:
                _flatten(decoded, "", flat)
            times.append(message.log_time)
            for key, value in flat.items():
                columns.setdefault(key, []).append(value)
    return times, columns


def assert_cdr_topics_decode_identically(path) -> int:
    """Every CDR topic of ``path``: mcap_ros2's values equal read_log's columns bit for bit; returns the count."""
    log = read_log(path)
    count = 0
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    cdr_topics = [c.topic for c in summary.channels.values() if c.message_encoding == "cdr"]
    assert cdr_topics
    for topic in cdr_topics:
        data = log.topic(topic)
        times, columns = independent_columns(path, topic)
        np.testing.assert_array_equal(data.log_time, times)
        assert set(columns) == set(data.fields) | set(data.text_fields), topic
        for key, values in columns.items():
            if key in data.text_fields:
                assert data.text(key) == values, (topic, key)
            else:  # bit-exact: the same float64 bits, NaN payloads included
                expected = np.array(values, dtype=np.float64)
                np.testing.assert_array_equal(data[key].view(np.uint64), expected.view(np.uint64), err_msg=f"{topic} {key}")
        count += len(times)
    return count


@pytest.fixture(scope="module")
def excavator_log(tmp_path_factory):
    """0.4 s of the excavator dig logged every step (1 kHz): every topic of a real run, NaN fields included."""
    out = tmp_path_factory.mktemp("cdr") / "dig.mcap"
    result = run(MODELS / "excavator" / "dig.scenario.toml", out=out, overrides={"duration": 0.4, "log_rate_hz": 1000.0})
    assert result.status == "complete"
    return result.log_path


def test_independent_decoder_reads_the_values_read_log_returns(excavator_log):
    check_message_indexes(excavator_log)  # the bulk writer's indexes point at the right records
    count = assert_cdr_topics_decode_identically(excavator_log)
    log = read_log(excavator_log)
    assert count == sum(n for topic, n in log.message_counts.items() if topic not in ("/hydroplant/scene", "/hydroplant/events"))
    joints = log.topic("/hydroplant/joint_states")
    assert np.isnan(joints["effort/boom"]).all() and np.isfinite(joints["position/boom"]).all()
    np.testing.assert_array_equal(log.topic("/hydroplant/cylinders/boom_cyl").log_time, np.arange(401) * 1_000_000)
    tf = log.topic("/tf")  # at the scenario's tf_rate_hz (100 Hz): every 10th sample, step 0 first
    np.testing.assert_array_equal(tf.log_time, np.arange(0, 401, 10) * 1_000_000)
    assert tf.text("parent_frame_id/boom") == ["world"] * 41


@pytest.mark.parametrize("tf_rate_hz, stride", [(100.0, 10), (1000.0, 1), (30.0, 33)])
def test_tf_at_its_rate_holds_the_poses_of_the_joints_logged_at_the_same_time(tmp_path, tf_rate_hz, stride):
    """/tf is a view of the joints: at each of its log times (every ``stride``-th step of a run logged every step),
    the body poses MuJoCo's kinematics gives for the joint positions logged at that time (the decimated rows
    are the right rows, and the joints and the hydraulics stay on every sample)."""
    scenario = MODELS / "boom" / "lift.scenario.toml"
    result = run(scenario, out=tmp_path / "lift.mcap",
                 overrides={"duration": 1.6, "log_rate_hz": 1000.0, "tf_rate_hz": tf_rate_hz})
    assert result.status == "complete"
    log = read_log(result.log_path)
    joints, tf = log.topic("/hydroplant/joint_states"), log.topic("/tf")
    assert len(log.topic("/hydroplant/cylinders/boom_cyl").log_time) == len(joints.log_time) == 1601
    np.testing.assert_array_equal(tf.log_time, np.arange(0, 1601, stride) * 1_000_000)
    check_message_indexes(result.log_path)
    with open(result.log_path, "rb") as stream:  # in file order: each channel's own count, in log-time order
        sequences = {}
        for _, channel, message in make_reader(stream).iter_messages(log_time_order=False):
            sequences.setdefault(channel.topic, []).append(message.sequence)
    assert sequences["/tf"] == list(range(1, len(tf.log_time) + 1))
    assert sequences["/hydroplant/cylinders/boom_cyl"] == list(range(1, 1602))
    model = mujoco.MjModel.from_xml_path(str(MODELS / "boom" / "boom.xml"))
    data = mujoco.MjData(model)
    rows = np.searchsorted(joints.log_time, tf.log_time)
    start = None
    for k, row in enumerate(rows):
        for j in range(model.njnt):
            data.qpos[model.jnt_qposadr[j]] = joints[f"position/{model.joint(j).name}"][row]
        mujoco.mj_kinematics(model, data)
        for body in range(1, model.nbody):
            name = model.body(body).name
            logged = [tf[f"translation.{axis}/{name}"][k] for axis in "xyz"]
            np.testing.assert_allclose(logged, data.xpos[body], rtol=0, atol=1e-12)
            quat = [tf[f"rotation.{axis}/{name}"][k] for axis in "wxyz"]
            assert abs(abs(np.dot(quat, data.xquat[body])) - 1.0) < 1e-12
        start = data.xpos.copy() if start is None else start
    assert np.abs(data.xpos - start).max() > 1e-2  # the boom rose: moving poses were compared, not one frozen pose


def test_merged_and_recovered_logs_decode_identically(excavator_log, tmp_path):
    """merge_logs rewrites the frame ids inside the CDR /tf messages; recover copies CDR messages as they are."""
    merged = tmp_path / "merged.mcap"
    merge_logs({"a": excavator_log, "b": excavator_log}, merged)
    assert_cdr_topics_decode_identically(merged)
    tf, original = read_log(merged).topic("/b/tf"), read_log(excavator_log).topic("/tf")
    assert tf.text("parent_frame_id/b/boom") == ["world"] * len(original)  # the shared root stays
    np.testing.assert_array_equal(tf["translation.z/b/boom"], original["translation.z/boom"])

    cut = tmp_path / "cut.mcap.partial"
    cut.write_bytes(excavator_log.read_bytes()[: excavator_log.stat().st_size * 2 // 3])
    report = recover(cut, tmp_path / "recovered.mcap")
    assert report.message_count > 0
    assert_cdr_topics_decode_identically(tmp_path / "recovered.mcap")


def test_cdr_layout_matches_the_reference_encoder():
    """Our CDR bytes equal mcap_ros2's own encoder's for the same values (alignment, strings, sequences, NaN), and the
    schema texts parse back to the same types."""
    from mcap_ros2._dynamic import serialize_dynamic

    flat = flat_schema("t_msgs/msg/S", {"a_m": "a [m]", "force.x": "x [N]", "force.y": "y [N]"})
    cases = [
        (flat, {"timestamp": {"sec": 3, "nanosec": 7}, "a_m": float("nan"), "force": {"x": -0.0, "y": 1e-310}}),
        (JOINT_STATES, {"timestamp": {"sec": 0, "nanosec": 999_999_999},
                        "joints": [{"name": n, "position": p, "velocity": 0.5, "acceleration": float("nan"), "effort": 2.0}
                                   for n, p in (("a", 1.0), ("boom", float("inf")), ("seven77", -3.0))]}),
        (FRAME_TRANSFORMS, {"transforms": [{"timestamp": {"sec": 1, "nanosec": 2}, "parent_frame_id": "world",
                                            "child_frame_id": c, "translation": {"x": 1.0, "y": 2.0, "z": 3.0},
                                            "rotation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}} for c in ("b", "stick")]}),
    ]
    for msg_type, message in cases:
        assert ros2msg_type(msg_type.name, msg_type.definition()) == msg_type
        reference = serialize_dynamic(msg_type.name, msg_type.definition())[msg_type.name](message)
        ours = cdr_encode(msg_type, message)
        assert ours == bytes(reference), msg_type.name
        decoded = cdr_decode(msg_type, ours)
        assert cdr_encode(msg_type, decoded) == ours
