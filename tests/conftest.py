"""Shared fixtures: paths, small circuits written inline, and a log's messages as written."""

import tomllib
from pathlib import Path

import pytest
from mcap.reader import make_reader

from hydraulics.circuit import parse_circuit
from hydraulics.network import NetworkModel

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"


def messages_by_topic(path) -> dict[str, list[tuple[int, int, bytes]]]:
    """Per topic of the MCAP file ``path``: (log time, sequence, message bytes) of its messages in file order."""
    out = {}
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            out.setdefault(channel.topic, []).append((message.log_time, message.sequence, bytes(message.data)))
    return out


def network_from_toml(text: str, *, source: str = "<test>", **options) -> NetworkModel:
    """Build a network from an inline circuit document."""
    return NetworkModel.from_circuit(parse_circuit(tomllib.loads(text), source), **options)


@pytest.fixture
def models_dir() -> Path:
    return MODELS


def scene_copy(tmp_path: Path, scene: str, edits: dict | None = None) -> Path:
    """Copy models/<scene> to ``tmp_path`` and apply text edits {file name: [(old, new), ...]}.

    Each ``old`` must occur exactly once, so a test never edits the wrong line silently.
    """
    import shutil

    target = tmp_path / scene
    shutil.copytree(MODELS / scene, target)
    for name, replacements in (edits or {}).items():
        path = target / name
        text = path.read_text()
        for old, new in replacements:
            assert text.count(old) == 1, f"{name}: {old!r} occurs {text.count(old)} times"
            text = text.replace(old, new)
        path.write_text(text)
    return target
