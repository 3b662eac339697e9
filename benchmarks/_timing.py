"""What the benchmark scripts share (run as `python benchmarks/NAME.py`, so importable as `_timing`): timing,
the header block of every results file and the figures' set-up.

Each `results_<name>.md` starts with its title and the block `header` writes: one line per field of
`HEADER_FIELDS` (`- Command: ...`), describing the run whose figures follow.
"""

from __future__ import annotations

import importlib.metadata
import os
import platform
import shlex
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import jax
import numpy as np

ROOT = Path(__file__).resolve().parents[1]
HEADER_FIELDS = ("Command", "Commit", "Machine", "Device", "Date", "Versions", "Peer")
"""The header's fields: the command line, the commit of the code measured, the CPU (model, cores) with
the 1-minute load average, the JAX device(s), the date (UTC), the versions of the packages timed, and
the peer measured in the same run."""
PACKAGES = ("jaxrobot", "identification", "planning")
START_TIME, START_LOAD = time.gmtime(), os.getloadavg()[0]
"""The script's start (it imports this module first) and the 1-minute load average then."""


def timed(fn, repeat: int = 1):
    """`(out, first, best)`: the result of `fn()`, the wall time of the first call (compile + run) and
    the best of `repeat` further calls, each until its arrays are ready."""
    start = time.perf_counter()
    out = jax.block_until_ready(fn())
    first = time.perf_counter() - start
    best = np.inf
    for _ in range(repeat):
        start = time.perf_counter()
        out = jax.block_until_ready(fn())
        best = min(best, time.perf_counter() - start)
    return out, first, best


def largest_relative_difference(a, b) -> float:
    """The largest `|a - b| / |a|` over the entries of two results of the same work (`a` the reference)."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b) / np.maximum(np.abs(a), 1e-300)))


def cpu_model() -> str:
    """The CPU's model name (`/proc/cpuinfo`), else what `platform` knows."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def commit(source: Path | None = None) -> str:
    """The short commit of the code measured (`source`, default this repository); `+ local changes` when
    its packages, this module or the running script differ from it."""
    where = source or ROOT
    git = lambda *a: subprocess.run(["git", "-C", str(where), *a], capture_output=True, text=True).stdout.strip()
    script = Path(sys.argv[0]).resolve()
    paths = [*PACKAGES, str(Path(__file__).relative_to(ROOT))]
    paths += [str(script.relative_to(where))] if script.is_relative_to(where) else []
    head = git("rev-parse", "--short", "HEAD") or "unknown"
    return head + (" + local changes" if git("status", "--porcelain", "--untracked-files=no", "--", *paths) else "")


START_COMMIT = commit()
"""The commit of the code measured, at the script's start."""


def run_info(peer: str, packages: tuple[str, ...] = (), command: str | None = None,
             source: Path | None = None) -> dict[str, str]:
    """The header fields (`HEADER_FIELDS`) of this run, at its end: `peer` names what the same run
    measured beside jaxrobot; `packages` are versions to add to Python, jax and numpy; `command`
    defaults to this process' command line; `source` is the code measured (default this repository)."""
    argv = [str(Path(sys.argv[0]).resolve().relative_to(ROOT)) if Path(sys.argv[0]).is_file() else sys.argv[0],
            *sys.argv[1:]]
    devices = jax.devices()
    versions = [f"Python {platform.python_version()}", f"jax {jax.__version__}", f"numpy {np.__version__}"]
    versions += [f"{p} {importlib.metadata.version(p)}" for p in packages]
    fmt = lambda t: time.strftime("%Y-%m-%d %H:%M", t)
    return {
        "Command": f"`{command or 'python ' + shlex.join(argv)}`",
        "Commit": START_COMMIT if source is None else commit(source),
        "Machine": f"{cpu_model()}, {os.cpu_count()} cores ({platform.system()} {platform.machine()}); load average "
                   f"(1 min) {START_LOAD:.1f} at the start, {os.getloadavg()[0]:.1f} at the end",
        "Device": f"{devices[0].platform} ({devices[0].device_kind}) x {len(devices)}",
        "Date": f"{fmt(START_TIME)} to {time.strftime('%H:%M', time.gmtime())} UTC",
        "Versions": ", ".join(versions),
        "Peer": peer,
    }


def header(info: dict[str, str]) -> str:
    """The header block of a results file: a line `- FIELD: value` per field of `HEADER_FIELDS`."""
    missing = [f for f in HEADER_FIELDS if not info.get(f)]
    if missing:
        raise ValueError(f"header: the run info lacks the fields {missing}; expected all of {list(HEADER_FIELDS)}")
    return "\n".join(f"- {f}: {info[f]}" for f in HEADER_FIELDS) + "\n"


def figure(title: str, info: dict[str, str]):
    """`(fig, ax)` of a new figure (matplotlib, Agg backend) titled `title` and, below it, the machine,
    device and commit of `info`."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7.0, 4.8), layout="constrained")
    where = textwrap.fill(f"{info['Machine'].split(';')[0]}; {info['Device']}; commit {info['Commit']}", 100)
    ax.set_title(f"{title}\n{where}", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    return fig, ax


def save(fig, path: Path) -> None:
    """Write `fig` as a PNG to `path` and close it."""
    import matplotlib.pyplot as plt

    fig.savefig(path, dpi=120)
    plt.close(fig)
