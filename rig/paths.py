"""Where the project's data files are, installed or in a source checkout."""

from __future__ import annotations

import os
from pathlib import Path


def data_dir() -> Path:
    """The `data/` directory: $ISOLATOR_DATA_DIR, the installed copy, or the checkout's."""
    override = os.environ.get("ISOLATOR_DATA_DIR")
    if override:
        return Path(override)
    installed = Path(__file__).with_name("_data")
    if installed.is_dir():
        return installed
    return Path(__file__).resolve().parent.parent / "data"


def data_file(*parts: str) -> Path:
    """A file under `data/`; FileNotFoundError names the full path if missing."""
    path = data_dir().joinpath(*parts)
    if not path.exists():
        raise FileNotFoundError(f"data file not found: {path}")
    return path
