"""Fixtures shared by the planning tests: the Racer-7, its reference paths, their joint paths and the
baseline trajectories of the line, built once per test process."""

from __future__ import annotations

import pytest

import jaxrobot as jr
import planning as pl


@pytest.fixture(scope="session")
def robot():
    return jr.racer7()


@pytest.fixture(scope="session")
def paths():
    return {name: pl.reference_path(name, jr.read_description(None)) for name in ("line", "spiral")}


@pytest.fixture(scope="session")
def joint_paths(robot, paths):
    return {name: pl.joint_path(robot, p) for name, p in paths.items()}


@pytest.fixture(scope="session")
def line_baselines(robot, joint_paths):
    jp = joint_paths["line"]
    return pl.baseline_trajectories(robot, jp)
