"""What every command shares: exit codes and the exceptions that carry them, the help formatter, the
robot option, progress on stderr, the figure backend, and JSON-ready summaries."""

from __future__ import annotations

import argparse
import difflib
import os
import sys
import time
from pathlib import Path

EXIT_CODES = {0: "success", 1: "internal error (a bug: please report it)", 2: "bad input or usage",
              3: "a solve did not converge (no result saved unless --save-failed)",
              4: "some items of a batch failed (named in the output; the others' results are saved)"}


class SolveFailed(Exception):
    """A solve that did not converge: `main` prints the message and exits with `code` (3), and with
    `--json` prints `summary` (the JSON summary of what was done) where one is given."""

    code = 3

    def __init__(self, message: str, summary: dict | None = None):
        super().__init__(message)
        self.summary = summary


class ItemsFailed(SolveFailed):
    """Some items of a batch failed (rejected input, no convergence, a fit beyond the noise) while the
    others succeeded: their statuses are in the output and `summary`; exit code 4."""

    code = 4


def suggestion(word: str, choices) -> str:
    """`"; did you mean 'x'?"` for the closest of `choices`, or `""`."""
    close = difflib.get_close_matches(word, list(choices), n=1)
    return f"; did you mean {close[0]!r}?" if close else ""


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Help texts with `(default: X)` appended where an option has a default its text does not state."""

    def _get_help_string(self, action) -> str:
        text, default = action.help or "", action.default
        if default is None or default is False or default == [] or default == argparse.SUPPRESS \
                or "default" in text or not action.option_strings:
            return text
        shown = " ".join(map(str, default)) if isinstance(default, (list, tuple)) else str(default)
        return f"{text} (default: {shown.replace('%', '%%')})"


def add_model_option(parser, help: str = "robot description, TOML or URDF (default: the embedded Racer-7-1.4)",
                     dest: str = "model") -> None:
    """`--model FILE` (alias `--robot`): the robot description (TOML, or a URDF) a command starts from."""
    parser.add_argument("--model", "--robot", dest=dest, type=Path, default=None, metavar="FILE", help=help)


class Progress:
    """Elapsed time and an ETA after each of `total` steps (at the mean step time so far), on stderr;
    `at_most`: `total` is an upper bound on the steps (the ETA too)."""

    def __init__(self, total: int, what: str, at_most: bool = False):
        self.total, self.what, self.at_most, self.done, self.start = total, what, at_most, 0, time.perf_counter()

    def step(self, label: str) -> None:
        self.done += 1
        elapsed = time.perf_counter() - self.start
        left = self.total - self.done
        eta = (f", ETA {'at most ' if self.at_most else ''}{elapsed / self.done * left:.0f} s" if left > 0
               else ", done")
        print(f"[{self.what} {self.done}/{self.total}] {label}: {elapsed:.0f} s elapsed{eta}",
              file=sys.stderr, flush=True)


def use_file_backend() -> None:
    """Figures of the command line go to files: matplotlib's Agg backend (no window, no display
    needed) unless the user chose a backend (`MPLBACKEND`) or has pyplot running already."""
    if "matplotlib.pyplot" not in sys.modules:
        os.environ.setdefault("MPLBACKEND", "Agg")


def jsonable(obj):
    """`obj` with arrays turned into (nested) lists and keys into strings: ready for `json.dumps`."""
    import numpy as np

    if isinstance(obj, dict):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [jsonable(v) for v in obj]
    if hasattr(obj, "tolist"):
        return jsonable(np.asarray(obj).tolist())
    return obj
