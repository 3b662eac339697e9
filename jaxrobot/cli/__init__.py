"""The `jaxrobot` command line and what a command of another package uses (CONTRIBUTING.md, "a CLI
command"): the robot option, progress on stderr, the failed-solve exits and the figure backend. A command
is a module with `HELP`, `EXAMPLE`, `configure(parser)` and `run(args, echo) -> dict`, registered under the
entry-point group `jaxrobot.commands`; `jaxrobot.cli._main.main` (the `jaxrobot` script,
`python -m jaxrobot.cli`) runs it."""

from ._common import EXIT_CODES as EXIT_CODES
from ._common import ItemsFailed as ItemsFailed
from ._common import Progress as Progress
from ._common import SolveFailed as SolveFailed
from ._common import add_model_option as add_model_option
from ._common import suggestion as suggestion
from ._common import use_file_backend as use_file_backend
