"""What every console script shares: one-line errors with exit code 2, never a traceback.

- RigError (a refused plan, a bad file: the message names the file and the
  problem), FileNotFoundError, KeyError and any other OSError (permission, a
  directory given for a file, no space) → `prog: error: …`, exit 2. A refused
  plan's violations follow, one per indented line: sixteen of them on one line
  were unreadable.
- Ctrl-C → `prog: interrupted`, exit 130 (a run in progress aborts in order
  first: rig.run.runner).
- Anything else is a bug → `prog: internal error: Type: message` on one line,
  exit 3; set RIG_TRACEBACK=1 to see the traceback.
"""

from __future__ import annotations

import argparse
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


# One vocabulary across the three CLIs: a table motion is chosen with --profile, and
# units are a system, us (in, lb, the report's) or si (m, N), for what is printed and
# for what a file holds. The older spellings still work, with a note that names the new.
UNIT_SYSTEMS = ("us", "si")
LENGTH_UNIT = {"us": "in", "si": "m"}  # what a file's displacements are in, per system
OLD_UNIT_WORDS = {"in": "us", "m": "si"}


def unit_system(text: str) -> str:
    """argparse type of --units: us or si; in and m are read as their system, with a note."""
    word = text.strip().lower()
    if word in UNIT_SYSTEMS:
        return word
    if word in OLD_UNIT_WORDS:
        new = OLD_UNIT_WORDS[word]
        print(f"note: --units {text} is the older spelling of --units {new} "
              f"({LENGTH_UNIT[new]}); it still works", file=sys.stderr)
        return new
    raise argparse.ArgumentTypeError(f"{text!r}: us (in, lb, the report's units) or si (m, N)")


def add_units_argument(p: argparse.ArgumentParser, default: str | None, what: str) -> None:
    """--units us|si; `what` says what it applies to, for --help."""
    shown = f"default {default}" if default else "default: from the file, else si"
    p.add_argument("--units", type=unit_system, default=default, metavar="us|si",
                   help=f"{what}: us (in, lb) or si (m, N) ({shown})")


def older_spelling(new: str) -> type[argparse.Action]:
    """An argparse action for an option's older name: stores under the new one's dest and
    says which name to use."""

    class Older(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):
            print(f"note: {option_string} is the older spelling of {new}; it still works",
                  file=sys.stderr)
            setattr(namespace, self.dest, values)

    return Older
