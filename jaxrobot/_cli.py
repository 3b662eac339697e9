"""The `jaxrobot` command line.

Subcommands are modules with `HELP: str`, `EXAMPLE: str` (a command line shown in the help),
`configure(parser)` and `run(args, echo) -> dict` (the JSON summary); `--out` is a folder, or the
file described by the module's `OUT_FILE: str`. Help texts show every default (`HelpFormatter`);
the robot description is `--model` everywhere (`add_model_option`; `--robot` is an alias); long
runs print elapsed time and ETA on stderr (`Progress`), so that `--json` keeps stdout clean.
`jaxrobot` ships `info`, `demo` and `import-urdf`; other packages add theirs through the
entry-point group `jaxrobot.commands`, and stages of `jaxrobot demo` through `jaxrobot.demo`
(a function `stage(out: Path, echo) -> dict`, run in the order of the entry-point names), so
that `jaxrobot` never imports the packages built on it.

Exit codes (`EXIT_CODES`): 0 success, 1 internal error, 2 bad input or usage, 3 a solve did not
converge (`SolveFailed`; nothing is saved as a result), 4 some items of a batch failed (`ItemsFailed`:
the others' results are saved). No traceback reaches the user; `--json` prints the summary a failure
carries.
"""

from __future__ import annotations

import argparse
import difflib
import json
import os
import sys
import time
from collections.abc import Callable
from importlib.metadata import entry_points
from pathlib import Path
from types import ModuleType

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


def _commands() -> dict[str, ModuleType]:
    from . import _cli_demo, _cli_import_urdf, _cli_info

    found = {"info": _cli_info, "demo": _cli_demo, "import-urdf": _cli_import_urdf}
    for ep in entry_points(group="jaxrobot.commands"):
        try:
            found[ep.name] = ep.load()
        except ImportError as err:  # a broken plugin must not take the other commands down
            print(f"jaxrobot: command '{ep.name}' unavailable ({err})", file=sys.stderr)
    return found


def demo_stages() -> list[tuple[str, Callable]]:
    """The registered stages of `jaxrobot demo`, in order."""
    return sorted(((ep.name, ep.load()) for ep in entry_points(group="jaxrobot.demo")),
                  key=lambda item: item[0])


def _jsonable(obj):
    import numpy as np

    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if hasattr(obj, "tolist"):
        return _jsonable(np.asarray(obj).tolist())
    return obj


def parser(commands: dict[str, ModuleType]) -> argparse.ArgumentParser:
    """The `jaxrobot` argument parser with one subparser per command."""
    top = argparse.ArgumentParser(
        prog="jaxrobot", description="Calibrated elastic-joint robot models and accurate offline planning.",
        epilog="exit codes: " + "; ".join(f"{k} {v}" for k, v in EXIT_CODES.items()))
    sub = top.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for name, module in commands.items():
        example = getattr(module, "EXAMPLE", None)
        p = sub.add_parser(name, help=module.HELP, description=module.HELP, formatter_class=HelpFormatter,
                           epilog=None if example is None else f"example:\n  {example}")
        p.add_argument("--json", action="store_true", help="print a machine-readable summary on stdout")
        p.add_argument("--out", type=Path, default=None,
                       help=getattr(module, "OUT_FILE", "folder for tables, plots and files"))
        module.configure(p)
    return top


def main(argv: list[str] | None = None) -> int:
    commands = _commands()
    argv = sys.argv[1:] if argv is None else list(argv)
    if argv and not argv[0].startswith("-") and argv[0] not in commands:
        print(f"jaxrobot: error: unknown command {argv[0]!r} (commands: {', '.join(commands)})"
              f"{suggestion(argv[0], commands)}", file=sys.stderr)
        return 2
    args = parser(commands).parse_args(argv)
    use_file_backend()
    stream = sys.stderr if args.json else sys.stdout

    def echo(text: str) -> None:
        print(text, file=stream, flush=True)

    def fail(message: str, code: int) -> int:
        print(f"jaxrobot {args.command}: error: {message}", file=sys.stderr)
        return code

    if args.out is not None and not hasattr(commands[args.command], "OUT_FILE"):
        if args.out.exists() and not args.out.is_dir():
            return fail(f"--out {args.out}: is an existing file; --out names a folder (it is created if missing)", 2)
        args.out.mkdir(parents=True, exist_ok=True)
    try:
        summary = commands[args.command].run(args, echo)
    except SolveFailed as err:
        if args.json and err.summary is not None:
            print(json.dumps(_jsonable(err.summary), indent=2))
        return fail(str(err), err.code)
    except (ValueError, OSError) as err:
        return fail(str(err), 2)
    except KeyboardInterrupt:
        return fail("interrupted", 130)
    except Exception as err:  # noqa: BLE001 - a bug: one line for the user, never a traceback
        return fail(f"internal error ({type(err).__name__}: {err}); please report it with the command line", 1)
    if args.json:
        print(json.dumps(_jsonable(summary), indent=2))
    return 0


if __name__ == "__main__":  # `python -m jaxrobot._cli`: the package's module, whose `SolveFailed` the commands raise
    from jaxrobot._cli import main as _main

    sys.exit(_main())
