"""One process of the 2-process nu sweep of `test_distributed.py` (not a test):

    python tests/sweep_worker.py HOST:PORT PROCESS_ID PROBLEM.npz RESULT.npz

`PROBLEM.npz` holds `q_d`, `ts`, `nus`; process 0 writes every field of the gathered sweep."""

import dataclasses
import sys

import jaxrobot as jr
from jaxrobot.internal import initialize_processes

initialize_processes(sys.argv[1], 2, int(sys.argv[2]))

import jax  # noqa: E402
import numpy as np  # noqa: E402

import planning as pl  # noqa: E402

problem = np.load(sys.argv[3])
sweep = pl.solve_ocp_sweep(jr.racer7(), problem["q_d"], float(problem["ts"]), problem["nus"])
if jax.process_index() == 0:
    fields = {f.name: np.asarray(getattr(sweep, f.name)) for f in dataclasses.fields(sweep) if f.name != "status"}
    np.savez(sys.argv[4], status=jr.status_name(sweep.status), **fields)
