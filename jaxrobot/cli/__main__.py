"""`python -m jaxrobot.cli`: the `jaxrobot` command."""

import sys

from ._main import main

sys.exit(main())
