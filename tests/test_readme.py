"""Every ```python block of README.md runs, top to bottom in one namespace (as a reader goes through
the README), in a temporary working directory. The files a block reads are made first: `panda.toml`
(example-robot-data's Panda imported, plus the README's own TOML fragment) and `fleet/` (pose files of
a few bench robots). The blocks together compile most of the package's programs (several minutes on
2 cores): they are marked `extended`: CI runs them after the suite (`.ci/run`)."""

from __future__ import annotations

import re
import tomllib
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import tomli_w
from helpers import example_urdf

import jaxrobot as jr
import jaxrobot.bench as jb
from identification import CATALOGUE

README = Path(__file__).resolve().parents[1] / "README.md"
TEXT = README.read_text()
BLOCKS = [(TEXT[: m.start()].count("\n") + 2, m.group(1))
          for m in re.finditer(r"^```python\n(.*?)^```", TEXT, re.S | re.M)]
"""(first line number, code) of each Python block."""
FLEET_ROBOTS = 3


def _panda_toml(path: Path) -> None:
    """`import-urdf panda.urdf --tip panda_link8`, completed by the README's TOML fragment of step 2
    (its `[limits]` line is a comment there: it goes into the existing section)."""
    fragment = re.search(r"^```toml\n(\[gear\].*?)^```", TEXT, re.S | re.M).group(1)
    acceleration = re.search(r"^# acceleration_deg_s2 = (\[.*\])$", fragment, re.M).group(1)
    jr.save_robot(jr.load_robot(example_urdf("panda.urdf"), tip="panda_link8"), path)
    desc = tomllib.loads(path.read_text())
    desc["limits"]["acceleration_deg_s2"] = [float(v) for v in acceleration.strip("[]").split(",")]
    path.write_text(tomli_w.dumps({**desc, **tomllib.loads(fragment)}))


def _fleet(folder: Path) -> None:
    """Pose files of `FLEET_ROBOTS` bench robots at the thesis poses (what `calibrate-fleet --bench`
    writes)."""
    folder.mkdir()
    theta = np.deg2rad(np.asarray(jr.read_description()["poses"]["motor_deg"], float))
    m = jb.measure_poses(jb.draw_fleet(FLEET_ROBOTS, seed=0), theta, seed=1)
    for r in range(FLEET_ROBOTS):
        jb.write_pose_csv(folder / f"robot{r}.csv", m.motor_angles[r], m.positions[r])


@pytest.fixture(scope="module")
def reader(tmp_path_factory):
    """The working directory and the namespace shared by the blocks."""
    return tmp_path_factory.mktemp("readme"), {"__name__": "readme"}


def _check_python_block(ns: dict) -> None:
    """The numbers the first block states: the flange at (0.834, 0, 1.25) m (to the 1 mm it is
    quoted with) and the flat inverse tracked on the simulated plant to < 1e-6 rad (the
    "Simulator" section)."""
    np.testing.assert_allclose(np.asarray(ns["T"])[:3, 3], [0.834, 0.0, 1.25], atol=5e-4)
    q_ref = jax.vmap(ns["q_d"])(ns["t"])
    assert float(jnp.max(jnp.abs(ns["q_sim"] - q_ref))) < 1e-6


CHECKS = {"jr.flat_inverse": _check_python_block}


@pytest.mark.extended
@pytest.mark.parametrize("index", [pytest.param(i, id=f"line{line}")
                                   for i, (line, code) in enumerate(BLOCKS)])
def test_readme_python_block(index, reader, monkeypatch):
    work, ns = reader
    line, code = BLOCKS[index]
    monkeypatch.chdir(work)
    if 'load_robot("panda.toml")' in code and not (work / "panda.toml").exists():
        _panda_toml(work / "panda.toml")
    if 'Path("fleet")' in code and not (work / "fleet").exists():
        _fleet(work / "fleet")
    catalogue = list(CATALOGUE)
    try:
        exec(compile(code, f"README.md:{line}", "exec"), ns)
    finally:
        CATALOGUE[:] = catalogue  # a block may extend the catalogue; other tests use the built-in one
    for key, check in CHECKS.items():
        if key in code:
            check(ns)


def test_readme_has_its_blocks():
    """The extraction finds the blocks (a README reformatted into other fences would run nothing)."""
    assert len(BLOCKS) >= 5
    assert all(code.strip() for _, code in BLOCKS)
