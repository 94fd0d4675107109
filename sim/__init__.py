"""The simulated rig: actuators, table, isolator, mass and sensors behind the rig's protocols."""

import rig  # noqa: F401  numpy's kernels chosen before numpy loads (rig/__init__.py)
