"""Identification of nonlinear shock isolators from logged runs (after CERL TR M-226)."""

import rig  # noqa: F401  numpy's kernels chosen before numpy loads (rig/__init__.py)
