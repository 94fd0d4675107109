"""`python -m sim …`: the same as the `sim` console script (the rig starts `sim serve` this way)."""

import sys

from sim.cli import main

sys.exit(main())
