"""What every console script shares: one-line errors with exit code 2, never a traceback."""

from __future__ import annotations

import sys
from collections.abc import Callable, Sequence

from rig.errors import RigError

EXIT_USAGE = 2


def guarded(main: Callable[[Sequence[str] | None], int], argv: Sequence[str] | None,
            prog: str) -> int:
    """Run `main(argv)`; a RigError or a missing file becomes `prog: error: …` and exit 2."""
    try:
        return main(argv)
    except (RigError, FileNotFoundError, KeyError) as e:
        message = e.args[0] if isinstance(e, KeyError) and e.args else e
        print(f"{prog}: error: {message}", file=sys.stderr)
        return EXIT_USAGE
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
