"""Every ```python block of README.md and of the pages of `docs/` runs, top to bottom in one namespace per
document (as a reader goes through a page), in a temporary working directory shared by all; the README's
command-line example runs command by command (`python -m jaxrobot.cli`, as the `jaxrobot` script). The files a
block reads are made first: `panda.toml` (example-robot-data's Panda imported, plus the TOML fragment of
`docs/own-robot.md`) and `fleet/` (pose files of a few bench robots). The blocks and commands together compile the
model, the flat inverse and simulator, the IK, the OCP, the calibration and the fleet calibration
(minutes on 2 cores): they are marked `extended`: CI runs them after the suite (`.ci/run`)."""

from __future__ import annotations

import re
import shlex
import subprocess
import sys
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
from identification.diagnosis import CATALOGUE

ROOT = Path(__file__).resolve().parents[2]
DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
"""The documents whose Python blocks run: the README, then the documentation pages."""
FENCE = re.compile(r"^```(\w+)\n(.*?)^```", re.S | re.M)


def fenced_blocks(path: Path, language: str) -> list[tuple[int, str]]:
    """(first line number, code) of each ```language block of a markdown file."""
    text = path.read_text()
    return [(text[: m.start()].count("\n") + 2, m.group(2)) for m in FENCE.finditer(text) if m.group(1) == language]


BLOCKS = [(path, line, code) for path in DOCUMENTS for line, code in fenced_blocks(path, "python")]
"""(document, first line, code) of every Python block."""
COMMANDS = [code for _, code in fenced_blocks(ROOT / "README.md", "bash")
            if all(line.startswith(("jaxrobot ", "#")) for line in code.splitlines() if line.strip())]
"""The README's command-line example: its bash block of `jaxrobot` command lines and comments only."""
FLEET_ROBOTS = 3


def _panda_toml(path: Path) -> None:
    """`import-urdf panda.urdf --tip panda_link8`, completed by the TOML fragment of `docs/own-robot.md` (its
    `[limits]` line is a comment there: it goes into the existing section)."""
    fragment = next(code for _, code in fenced_blocks(ROOT / "docs" / "own-robot.md", "toml")
                    if code.startswith("[gear]"))
    acceleration = re.search(r"^# acceleration_deg_s2 = (\[.*\])$", fragment, re.M).group(1)
    jr.save_robot(jr.load_robot(example_urdf("panda.urdf"), tip="panda_link8"), path)
    desc = tomllib.loads(path.read_text())
    desc["limits"]["acceleration_deg_s2"] = [float(v) for v in acceleration.strip("[]").split(",")]
    path.write_text(tomli_w.dumps({**desc, **tomllib.loads(fragment)}))


def _fleet(folder: Path) -> None:
    """Pose files of `FLEET_ROBOTS` bench robots at the thesis poses (what `calibrate-fleet --bench` writes)."""
    folder.mkdir()
    theta = np.deg2rad(np.asarray(jr.read_description()["poses"]["motor_deg"], float))
    m = jb.measure_poses(jb.draw_fleet(FLEET_ROBOTS, seed=0), theta, seed=1)
    for r in range(FLEET_ROBOTS):
        jr.io.write_poses(folder / f"robot{r}.csv", m.motor_angles[r], m.positions[r])


@pytest.fixture(scope="module")
def reader(tmp_path_factory):
    """The working directory shared by the blocks and a namespace per document."""
    return tmp_path_factory.mktemp("docs"), {}


def _check_model_block(ns: dict) -> None:
    """The README's example: the flange at (0.834, 0, 1.25) m (to the 1 mm it is quoted with), a batch of mass
    matrices, and the flange height's derivative by the link lengths (1 for a2, a3 along z at this pose: the DH
    x axes of links 2 and 3 point up; 0 for the horizontal a1)."""
    np.testing.assert_allclose(np.asarray(ns["T"])[:3, 3], [0.834, 0.0, 1.25], atol=5e-4)
    assert ns["Ds"].shape == (1000, 6, 6)
    np.testing.assert_allclose(np.asarray(ns["dz"].a)[:3], [0.0, 1.0, 1.0], atol=1e-12)


def _check_flat_inverse_block(ns: dict) -> None:
    """The getting-started page's statement: the flat inverse tracked on the simulated plant to < 1e-6 rad."""
    q_ref = jax.vmap(ns["q_d"])(ns["t"])
    assert float(jnp.max(jnp.abs(ns["q_sim"] - q_ref))) < 1e-6


CHECKS = {"eqx.filter_grad": _check_model_block, "jr.flat_inverse": _check_flat_inverse_block}
"""A substring of a block -> the check of the numbers it states."""


@pytest.mark.extended
@pytest.mark.parametrize("index", [pytest.param(i, id=f"{path.name}:{line}") for i, (path, line, _) in
                                   enumerate(BLOCKS)])
def test_python_block(index, reader, monkeypatch):
    work, namespaces = reader
    path, line, code = BLOCKS[index]
    ns = namespaces.setdefault(path, {"__name__": path.stem})
    monkeypatch.chdir(work)
    if 'load_robot("panda.toml")' in code and not (work / "panda.toml").exists():
        _panda_toml(work / "panda.toml")
    if 'Path("fleet")' in code and not (work / "fleet").exists():
        _fleet(work / "fleet")
    catalogue = list(CATALOGUE)
    try:
        exec(compile(code, f"{path.relative_to(ROOT)}:{line}", "exec"), ns)
    finally:
        CATALOGUE[:] = catalogue  # a block may extend the catalogue; other tests use the built-in one
    for key, check in CHECKS.items():
        if key in code:
            check(ns)


@pytest.mark.extended
def test_readme_commands(tmp_path):
    """The README's command lines, each exiting 0, in one folder; then the files they name: the fleet's table (a row
    per bench robot), the calibrated robot and the planned motor command (2501 samples of the 2.5 s line at 1 ms)."""
    for line in [c for c in COMMANDS[0].splitlines() if c.startswith("jaxrobot ")]:
        args = shlex.split(line, comments=True)[1:]
        done = subprocess.run([sys.executable, "-m", "jaxrobot.cli", *args], cwd=tmp_path, capture_output=True,
                              text=True, timeout=600)
        assert done.returncode == 0, f"{line}\nexit {done.returncode}\n{done.stderr[-3000:]}"
    assert len((tmp_path / "fleet-out" / "fleet_calibration.csv").read_text().splitlines()) == 1 + 20
    jr.load_robot(tmp_path / "robot0.toml")
    t, theta, _, _ = jr.io.read_command_csv(tmp_path / "line.csv")
    assert t.shape == (2501,) and theta.shape == (2501, 6)


def test_blocks_are_found():
    """The extraction finds the blocks (a document reformatted into other fences would run nothing): the README's
    Python example and command lines, and the Python blocks of the pages."""
    assert [p for p, _, _ in BLOCKS].count(ROOT / "README.md") == 1
    assert len(COMMANDS) == 1 and sum(c.startswith("jaxrobot ") for c in COMMANDS[0].splitlines()) == 4
    assert len(BLOCKS) >= 5
    assert all(code.strip() for _, _, code in BLOCKS)
