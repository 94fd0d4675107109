"""Cleaning up after a third-party reader that failed to open a file.

Two readers the foreign-format paths use leave half-built objects behind when a
file is corrupt: asammdf (8.8) closes the file but keeps the MDF4/MDF3 object with
its scratch file open, and its `__del__` later raises AttributeError, printed as
"Exception ignored in MDF4.__del__" after our one-line error; a python-can log
reader whose header fails keeps its file open (a ResourceWarning). `release(exc)`
finds them in the frames the exception passed through and closes what they hold.
"""

from __future__ import annotations

import contextlib


def release(exc: BaseException) -> None:
    """Close what the half-built readers in `exc`'s traceback hold; never raises."""
    import can  # here, not at the top: `analysis fit` on CSV files never needs python-can

    tb = exc.__traceback__
    while tb is not None:
        obj = tb.tb_frame.f_locals.get("self")
        tb = tb.tb_next
        with contextlib.suppress(Exception):
            if type(obj).__name__ in ("MDF4", "MDF3") and hasattr(obj, "_closed"):
                obj._closed = True  # its close() now returns at once
                if getattr(obj, "_tempfile", None) is not None:
                    obj._tempfile.close()
            elif isinstance(obj, can.io.generic.MessageReader):
                obj.file.close()
