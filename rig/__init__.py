"""Test-rig controller: profiles, actuator commands, limit checks, acquisition, run files.

`rig` is the base layer of the project: it imports neither `analysis` nor `sim`. Each of
them imports it first, so what is set here holds before any of them loads numpy.
"""

import os
import platform

__version__ = "0.1.0"

# numpy chooses its kernels for exp, power, log, tanh … by the CPU's instruction sets
# when it loads (on x86-64: AVX2, AVX-512), and each set's kernels round the last bit
# their own way. Identification and the loop amplify a last bit (where friction sticks
# moves in steps with a constant), so constants, and on some campaigns which valley a
# fit ends in, follow the CPU (docs/analysis.md has campaigns where the named effect
# did). Its baseline kernels, chosen before numpy loads, are the same on every
# x86-64 CPU (docs/analysis.md, "What is reproducible across machines"); a setting the
# user made is left as it is.
NUMPY_KERNELS_OFF = "X86_V3 X86_V4 AVX512_ICL AVX512_SPR"
if platform.machine().lower() in ("x86_64", "amd64"):
    os.environ.setdefault("NPY_DISABLE_CPU_FEATURES", NUMPY_KERNELS_OFF)
