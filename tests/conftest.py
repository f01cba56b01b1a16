"""Shared fixtures for the Python tests; the repository root on sys.path for support/."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest

import sabre

# The repository root, so tests import support/ (what tests, benches and experiments share).
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


@pytest.fixture(scope="session")
def scene() -> sabre.Scene:
    """The built-in RoyalPanda in front of the shelf (default placement)."""
    return sabre.Scene.load("royalpanda", "shelf")


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20240611)


@pytest.fixture
def random_q(rng: np.random.Generator):
    """random_q(scene): a configuration strictly inside the joint limits, base translation within ±2 m."""

    def draw(scene: sabre.Scene, base_range: float = 2.0) -> np.ndarray:
        lower = np.maximum(scene.q_lower, -base_range) + 0.05
        upper = np.minimum(scene.q_upper, base_range) - 0.05
        return rng.uniform(lower, upper)

    return draw
