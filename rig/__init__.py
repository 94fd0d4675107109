"""Test-rig controller: profiles, actuator commands, limit checks, acquisition, run files.

`rig` is the base layer of the project: it imports neither `analysis` nor `sim`.
"""

__version__ = "0.1.0"
