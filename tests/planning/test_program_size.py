"""The OCP solve's program holds no array of the node count as a constant: the nodes are a traced axis (an
(N, 5n, 5n) constant baked in from numpy made the program 21 MB at N = 2904)."""

import jaxrobot as jr  # noqa: I001  (x64 first)
import math
import re

import jax
import jax.numpy as jnp
import pytest
from helpers import ARM7

import planning as pl
from planning import _ocp
from planning import _transcription as tr

NODES = 2904
"""The padded size of `plan line` (2501 samples); larger than any constant the program needs (a 5n x 5n block:
900 entries for 6 joints, 1225 for 7)."""


def _constant_sizes(text: str) -> list[int]:
    """The entry counts of the constants in StableHLO text."""
    shapes = re.findall(r"stablehlo\.constant dense<[^>]*> : tensor<([0-9x]*)f64>", text)
    return [math.prod(int(d) for d in s.split("x") if d) for s in shapes]


@pytest.mark.parametrize("name", ["racer7", "arm7"])
def test_no_constant_of_the_node_count(name):
    robot = jr.racer7() if name == "racer7" else jr.load_robot(ARM7)
    n = 40
    s = jnp.arange(n) / (n - 1)
    blend = s**4 * (35.0 - 84.0 * s + 70.0 * s**2 - 20.0 * s**3)
    q_d = jnp.full((n, robot.n_joints), 0.1) + 3e-4 * blend[:, None]  # a 0.3 mrad move (eq. 4.4 blend)
    problem = tr.pad_problem(tr.ocp_problem(robot, q_d, 1e-3, 1e-14, direction=jnp.ones_like(q_d)), NODES)
    config = jax.tree.map(jnp.asarray, pl.AugmentedLagrangian())
    m = pl.AugmentedLagrangian().history_length()
    text = jax.jit(lambda p, c: _ocp._solve.__wrapped__(p, None, c, m, False)).lower(problem, config).as_text()
    sizes = _constant_sizes(text)
    assert len(sizes) > 10  # the pattern finds the program's constants
    assert max(sizes) < NODES, sorted(sizes)[-3:]
