"""Shared fixtures: small scenarios that keep the suite fast."""
from __future__ import annotations

import numpy as np
import pytest

from zentrack.fusion.scenario import builtin_spec, simulate


@pytest.fixture(scope="session")
def exp2_small():
    """Experiment 2 (bearing), 6 nodes, 120 steps, 3 runs."""
    return simulate(builtin_spec("exp2", nodes=6, steps=120), runs=3, seed=11)


@pytest.fixture
def rng():
    return np.random.default_rng(1234)
