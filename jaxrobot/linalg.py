"""Small dense linear algebra that never hands LAPACK a batch of matrices (`jaxrobot._linalg`): use
these on every CPU path instead of batched `jnp.linalg` calls."""

from ._checks import check_public as _check_public
from ._linalg import map_matrices as map_matrices
from ._linalg import solve as solve
from ._linalg import spd_solve as spd_solve

_check_public(globals())
