"""The command line's help texts (issue 17): `--model` (alias `--robot`) wherever a command takes a
robot, every default shown, an example per command that the parser accepts, and the progress lines."""

from __future__ import annotations

import argparse
import re
import shlex
from pathlib import Path

import pytest

from jaxrobot.cli import _common, _main
from jaxrobot.cli._common import HelpFormatter, Progress
from jaxrobot.cli._main import main

COMMANDS = _main._commands()
WITHOUT_ROBOT = {"demo", "import-urdf"}


def _subparsers() -> dict[str, argparse.ArgumentParser]:
    top = _main.parser(COMMANDS)
    return next(a for a in top._actions if isinstance(a, argparse._SubParsersAction)).choices


def _help(name: str, capsys) -> str:
    with pytest.raises(SystemExit) as exit_info:
        main([name, "--help"])
    assert exit_info.value.code == 0
    return capsys.readouterr().out


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_help_shows_model_option_defaults_and_an_example(name, capsys):
    text = _help(name, capsys)
    assert f"example:\n  jaxrobot {name} " in text
    if name not in WITHOUT_ROBOT:
        # argparse writes the metavar after each alias up to Python 3.12, after the last one from 3.13
        assert re.search(r"--model( FILE)?, --robot FILE", text)
    formatter = HelpFormatter(prog="jaxrobot")
    for action in _subparsers()[name]._actions:
        shown = formatter._get_help_string(action)
        if action.option_strings and action.default not in (None, False, [], argparse.SUPPRESS):
            assert "default" in shown, (name, action.option_strings, shown)


@pytest.mark.parametrize("name,option,shown", [
    ("calibrate", "--limits", "(default: flag)"), ("plan", "--plant", "(default: model)"),
    ("sweep", "--plant", "(default: model)"), ("sweep", "--costs", "(default: thesis jerk flat)"),
    ("plan", "--cost", "(default: thesis)"), ("demo", "--out", "(default: jaxrobot-demo)")])
def test_help_states_the_default(name, option, shown, capsys):
    lines = _help(name, capsys).splitlines()
    first = next(i for i, line in enumerate(lines) if line.strip().startswith(option + " "))
    end = next((i for i, line in enumerate(lines[first + 1:]) if line.strip().startswith("-") or not line.strip()),
               len(lines))
    entry = " ".join(" ".join(lines[first: first + 1 + end]).split())  # argparse wraps the text
    assert shown in entry, entry


@pytest.mark.parametrize("name", sorted(COMMANDS))
def test_example_parses(name):
    argv = shlex.split(COMMANDS[name].EXAMPLE)
    assert argv[:2] == ["jaxrobot", name]
    args = _main.parser(COMMANDS).parse_args(argv[1:])
    assert args.command == name


@pytest.mark.parametrize("name", sorted(set(COMMANDS) - WITHOUT_ROBOT))
def test_robot_is_an_alias_of_model(name):
    example = shlex.split(COMMANDS[name].EXAMPLE)[1:]
    example = [a for i, a in enumerate(example) if a != "--model" and (i == 0 or example[i - 1] != "--model")]
    parser = _main.parser(COMMANDS)
    model, robot = (vars(parser.parse_args([*example, flag, "arm.toml"])) for flag in ("--model", "--robot"))
    assert model == robot
    assert Path("arm.toml") in model.values()


def test_progress_reports_elapsed_time_and_eta(monkeypatch, capsys):
    clock = iter([100.0, 110.0, 130.0, 145.0])
    monkeypatch.setattr(_common.time, "perf_counter", lambda: next(clock))
    progress = Progress(3, "sweep")
    for label in ("thesis", "jerk", "flat"):
        progress.step(f"cost {label}")
    out = capsys.readouterr()
    assert out.out == ""
    assert out.err.splitlines() == ["[sweep 1/3] cost thesis: 10 s elapsed, ETA 20 s",  # 10 s per step so far
                                    "[sweep 2/3] cost jerk: 30 s elapsed, ETA 15 s",
                                    "[sweep 3/3] cost flat: 45 s elapsed, done"]
    monkeypatch.setattr(_common.time, "perf_counter", iter([0.0, 4.0]).__next__)
    Progress(6, "diagnose", at_most=True).step("step 0")
    assert capsys.readouterr().err == "[diagnose 1/6] step 0: 4 s elapsed, ETA at most 20 s\n"
