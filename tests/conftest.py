"""`--runslow` runs the long checks (full-size OCP solves and sweeps); by default they are skipped
so that the suite stays within 10 minutes on 2 CPU cores."""

from __future__ import annotations

import pytest


def pytest_addoption(parser):
    parser.addoption("--runslow", action="store_true", help="also run tests marked slow (about 30 min on 2 cores)")


def pytest_configure(config):
    config.addinivalue_line("markers", "slow: a long check (full-size OCP, sweeps); run with --runslow")


def pytest_collection_modifyitems(config, items):
    if config.getoption("--runslow"):
        return
    skip = pytest.mark.skip(reason="slow: run with --runslow")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
