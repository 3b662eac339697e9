"""`python -m jaxrobot.cli`: the `jaxrobot` command."""

from ._main import console

console()
