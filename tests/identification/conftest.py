"""Fixtures shared by the identification tests."""

from __future__ import annotations

import pytest
from helpers import ARM7

import jaxrobot as jr


@pytest.fixture(scope="module")
def arm7():
    return jr.load_robot(ARM7), jr.load_robot(ARM7, as_built=True)
