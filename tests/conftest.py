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
