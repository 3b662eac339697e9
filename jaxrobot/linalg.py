"""Small dense linear algebra that never hands LAPACK a batch of matrices (`jaxrobot._linalg`): use
these on every CPU path instead of batched `jnp.linalg` calls."""

from ._linalg import cholesky as cholesky
from ._linalg import cholesky_solve as cholesky_solve
from ._linalg import inverse_cholesky_factor as inverse_cholesky_factor
from ._linalg import map_matrices as map_matrices
from ._linalg import solve as solve
from ._linalg import spd_solve as spd_solve
