"""The `jaxrobot` command line.

Subcommands are modules with `HELP: str`, `EXAMPLE: str` (a command line shown in the help),
`configure(parser)` and `run(args, echo) -> dict` (the JSON summary); `--out` is a folder, or the
file described by the module's `OUT_FILE: str`. Help texts show every default (`HelpFormatter`);
the robot description is `--model` everywhere (`add_model_option`; `--robot` is an alias); long
runs print elapsed time and ETA on stderr (`Progress`), so that `--json` keeps stdout clean; these shared
pieces are in `_common` (public as `jaxrobot.cli`). `jaxrobot` ships `info`, `demo` and `import-urdf`;
other packages add theirs through the
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
import json
import os
import sys
from importlib import import_module
from importlib.metadata import entry_points
from pathlib import Path
from types import ModuleType

from ._common import EXIT_CODES, HelpFormatter, SolveFailed, jsonable, suggestion, use_file_backend

_BUILTIN = {"info": "._info", "demo": "._demo", "import-urdf": "._import_urdf"}
"""`jaxrobot`'s own commands and their modules."""


def _commands() -> dict[str, ModuleType]:
    """Every command by name, its module imported."""
    found = {name: import_module(module, __package__) for name, module in _BUILTIN.items()}
    for ep in entry_points(group="jaxrobot.commands"):
        try:
            found[ep.name] = ep.load()
        except ImportError as err:  # a broken plugin must not take the other commands down
            print(f"jaxrobot: command '{ep.name}' unavailable ({err})", file=sys.stderr)
    return found


def _command(name: str) -> dict[str, ModuleType] | None:
    """`{name: module}` of the command `name` alone, its module imported (a command's run imports no other's);
    None where `name` is no command or its module does not import (`_commands` then names the cause)."""
    if name in _BUILTIN:
        return {name: import_module(_BUILTIN[name], __package__)}
    found = entry_points(group="jaxrobot.commands", name=name)
    try:
        return {name: next(iter(found)).load()} if found else None
    except ImportError:
        return None


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
    argv = sys.argv[1:] if argv is None else list(argv)
    commands = (_command(argv[0]) if argv else None) or _commands()
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
            print(json.dumps(jsonable(err.summary), indent=2))
        return fail(str(err), err.code)
    except (ValueError, OSError) as err:
        return fail(str(err), 2)
    except KeyboardInterrupt:
        return fail("interrupted", 130)
    except Exception as err:  # noqa: BLE001 - a bug: one line for the user, never a traceback
        return fail(f"internal error ({type(err).__name__}: {err}); please report it with the command line", 1)
    if args.json:
        print(json.dumps(jsonable(summary), indent=2))
    return 0


def console() -> None:
    """The `jaxrobot` script: `main`, then the process ends at once, its output flushed, without the interpreter's
    teardown (JAX's release of its backend and of every loaded program), which a finished command does not need."""
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)
