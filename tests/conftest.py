"""Shared fixtures. Tests import the installed csb package, never the source tree."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture
def rng() -> np.random.Generator:
    return np.random.default_rng(20071)
