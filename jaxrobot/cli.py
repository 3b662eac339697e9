"""What a command of another package uses (CONTRIBUTING.md, "a CLI command"): the robot option,
progress on stderr, the failed-solve exits and the figure backend. A command is a module with `HELP`,
`EXAMPLE`, `configure(parser)` and `run(args, echo) -> dict`, registered under the entry-point group
`jaxrobot.commands`; `jaxrobot._cli` runs it."""

from ._cli import EXIT_CODES as EXIT_CODES
from ._cli import ItemsFailed as ItemsFailed
from ._cli import Progress as Progress
from ._cli import SolveFailed as SolveFailed
from ._cli import add_model_option as add_model_option
from ._cli import suggestion as suggestion
from ._cli import use_file_backend as use_file_backend
