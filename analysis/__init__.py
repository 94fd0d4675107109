"""Identification of nonlinear shock isolators from logged runs (after CERL TR M-226)."""

import numpy
import scipy.linalg  # loads scipy's own BLAS, so that the limit below reaches it
from threadpoolctl import threadpool_limits

# The fits run their simulations on every core (numba, one row per thread). The
# matrices BLAS sees here are small (a few thousand samples × ten constants), and
# BLAS threads on them only fight the simulation threads for the same two cores:
# measured, a 9000 × 10 SVD took 93 ms with two BLAS threads on a busy machine and
# 2.5 ms with one, and `identify` 3.1–3.7 s against 1.8–2.5 s.
threadpool_limits(limits=1, user_api="blas")

del numpy, scipy, threadpool_limits
