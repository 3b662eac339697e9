"""Infrastructure shared by `jaxrobot`, `identification` and `planning`, not part of the modelling API
(as `optimistix.internal`): small linear algebra that never hands LAPACK a batch of matrices, the
status helpers beside `jaxrobot.RESULTS`, argument checks, deprecated aliases, processes and the
program cache. Names here may change between releases without an alias."""

from .._batch import backend_kind as backend_kind
from .._checks import check_public as check_public
from .._checks import checked as checked
from .._deprecation import deprecated_aliases as deprecated_aliases
from .._deprecation import public_names as public_names
from .._deprecation import renamed_argument as renamed_argument
from .._distributed import PROCESS_ENV as PROCESS_ENV
from .._distributed import gather_array as gather_array
from .._distributed import gather_rows as gather_rows
from .._distributed import gather_texts as gather_texts
from .._distributed import initialize_processes as initialize_processes
from .._distributed import process_share as process_share
from .._distributed import shard_rows as shard_rows
from .._elasticity import require_elastic as require_elastic
from .._linalg import cholesky as cholesky
from .._linalg import cholesky_solve as cholesky_solve
from .._linalg import inverse_cholesky_factor as inverse_cholesky_factor
from .._linalg import map_matrices as map_matrices
from .._linalg import solve as solve
from .._linalg import spd_solve as spd_solve
from .._program_cache import cached_program as cached_program
from .._program_cache import compile_timer as compile_timer
from .._program_cache import preparing as preparing
from .._status import check as check
from .._status import full as full
from .._status import require_successful as require_successful
from .._status import where as where
from ..io._instruments import bench_instruments as bench_instruments
