"""What a solver needs besides `jaxrobot.RESULTS` (`jaxrobot._status`): `check` raises a status's
message for `throw=True` (also under `jit`), `where` and `full` select and broadcast statuses,
`require_successful` raises on the host for a concrete status."""

from ._status import check as check
from ._status import full as full
from ._status import require_successful as require_successful
from ._status import where as where
