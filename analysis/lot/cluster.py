"""The Dask cluster a lot runs on: a local one sized to the machine, or one that exists.

Local: one worker process per core, one thread each. A unit's fit is hundreds of
simulations that numba would spread over every core, and BLAS would thread its
solves; with one such fit per core they would only fight each other for the cores, so
every worker process starts with `WORKER_ENV` (numba, OpenMP and BLAS on one thread;
set before the process starts, as numba reads it on import) and each task also puts
numba's threads for itself at one (`unit.one_core`). The parallelism is across units.

Existing (`--scheduler tcp://host:8786`): the workers must import this package and
read the units' directories by the paths given (a shared filesystem). Start them one
thread per core with the same environment, and without the profiler, e.g.

    NUMBA_NUM_THREADS=1 OMP_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 \\
    DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False \\
        dask worker tcp://host:8786 --nworkers 8 --nthreads 1
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

from rig.errors import ConfigError

if TYPE_CHECKING:
    from dask.distributed import Client

WORKER_ENV = {"NUMBA_NUM_THREADS": 1, "OMP_NUM_THREADS": 1, "OPENBLAS_NUM_THREADS": 1,
              "MKL_NUM_THREADS": 1}
CONNECT_TIMEOUT = "10s"


def cores() -> int:
    """The cores this process may run on (its affinity, else the machine's)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


@contextmanager
def connect(scheduler: str | None = None, workers: int | None = None) -> Iterator[Client]:
    """A client of the cluster at `scheduler`, or of a local cluster of `workers` worker
    processes (default: one per core), closed (and the local cluster shut down) on exit."""
    import dask
    from dask.distributed import Client, LocalCluster  # only when a lot is run

    if scheduler:
        try:
            client = Client(scheduler, timeout=CONNECT_TIMEOUT)
        except OSError as e:
            raise ConfigError("--scheduler", scheduler, f"cannot connect: {e}") from None
        with client:
            yield client
        return
    if workers is not None and workers < 1:
        raise ConfigError("--workers", str(workers), "needs at least one worker")
    environ = {**dask.config.get("distributed.nanny.pre-spawn-environ", {}), **WORKER_ENV}
    # the statistical profiler samples every worker's stack each 10 ms from its event loop:
    # measured, 5 % of a core beside a fit, 2 % without it; nobody reads its profiles here
    with dask.config.set({"distributed.nanny.pre-spawn-environ": environ,
                          "distributed.worker.profile.enabled": False}):
        cluster = LocalCluster(n_workers=workers or cores(), threads_per_worker=1,
                               processes=True, dashboard_address=None)
    with cluster, Client(cluster) as client:
        yield client
