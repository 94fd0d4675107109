"""A JSON document read from a file, its reader's complaints naming the file.

The fit's JSON is read by the TUI (`rig/tui/fit_summary.py`) and by `analysis`
(`analysis/model/model_json.py`); both want one line naming the file for a file
that is not JSON and for a document their reader refuses.
"""

from __future__ import annotations

import json
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from rig.errors import DataError

T = TypeVar("T")


def read_document(path: str | os.PathLike[str], read: Callable[[Any], T]) -> T:
    """`read` of the JSON document in the file at `path`; DataError names the file."""
    try:
        doc = json.loads(Path(path).read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as e:
        raise DataError(f"{path}: not a JSON file: {e}") from None
    try:
        return read(doc)
    except DataError as e:
        raise DataError(f"{path}: {e}") from None
