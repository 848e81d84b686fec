"""Shared fixtures: paths and small circuits written inline."""

import tomllib
from pathlib import Path

import pytest

from hydraulics.circuit import parse_circuit
from hydraulics.network import NetworkModel

ROOT = Path(__file__).resolve().parents[1]
MODELS = ROOT / "models"


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
