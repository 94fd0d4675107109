"""What every console script shares: one-line errors with exit code 2, never a traceback.

- RigError (a refused plan, a bad file: the message names the file and the
  problem), FileNotFoundError, KeyError and any other OSError (permission, a
  directory given for a file, no space) → `prog: error: …`, exit 2. A refused
  plan's violations follow, one per indented line: sixteen of them on one line
  were unreadable.
- Ctrl-C → `prog: interrupted`, exit 130 (a run in progress aborts in order
  first: rig.runner).
- Anything else is a bug → `prog: internal error: Type: message` on one line,
  exit 3; set RIG_TRACEBACK=1 to see the traceback.
"""

from __future__ import annotations

import os
import sys
import traceback
from collections.abc import Callable, Sequence

from rig.errors import LimitError, RigError

EXIT_USAGE = 2
EXIT_INTERNAL = 3
TRACEBACK_ENV = "RIG_TRACEBACK"


def guarded(main: Callable[[Sequence[str] | None], int], argv: Sequence[str] | None,
            prog: str) -> int:
    """Run `main(argv)`; turn every exception into one line on stderr and an exit code."""
    try:
        return main(argv)
    except LimitError as e:  # its lines are deliberate: one violation each
        head, *rest = str(e).splitlines() or [""]
        code = _error(prog, "error", head, EXIT_USAGE)
        for line in rest:
            print(f"  {line}", file=sys.stderr)
        return code
    except (RigError, FileNotFoundError, KeyError) as e:
        message = e.args[0] if isinstance(e, KeyError) and e.args else e
        return _error(prog, "error", str(message), EXIT_USAGE)
    except OSError as e:
        where = f"{e.filename}: " if e.filename else ""
        return _error(prog, "error", f"{where}{e.strerror or e}", EXIT_USAGE)
    except KeyboardInterrupt:
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130
    except Exception as e:  # a bug: still one line, unless asked for the traceback
        if os.environ.get(TRACEBACK_ENV):
            traceback.print_exc()
        return _error(prog, "internal error", f"{type(e).__name__}: {e} (set "
                      f"{TRACEBACK_ENV}=1 for the traceback)", EXIT_INTERNAL)


def _error(prog: str, kind: str, message: str, code: int) -> int:
    print(f"{prog}: {kind}: {' '.join(message.split())}", file=sys.stderr)
    return code
