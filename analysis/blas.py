"""BLAS on one thread, for a process that is about to fit or simulate.

The fits run their simulations on every core (numba, one row per thread). The
matrices BLAS sees here are small (a few thousand samples × ten constants), and
BLAS threads on them only fight the simulation threads for the same two cores:
measured, a 9000 × 10 SVD took 93 ms with two BLAS threads on a busy machine and
2.5 ms with one, and `identify` 3.1–3.7 s against 1.8–2.5 s.

Called where a process starts numerical work by our choice (the `analysis` CLI,
`sim`'s computing subcommands, the benchmarks, the test suite), not on import: a
process that only imports the model (`sim serve`) keeps its libraries' defaults.
"""

from __future__ import annotations


def one_blas_thread() -> None:
    """Limit every BLAS loaded in this process, numpy's and scipy's, to one thread."""
    import numpy  # noqa: F401
    import scipy.linalg  # noqa: F401  loads scipy's own BLAS, so that the limit reaches it
    from threadpoolctl import threadpool_limits

    threadpool_limits(limits=1, user_api="blas")
