"""Each unit's result kept as one JSON file, so that a lot interrupted halfway is finished
by running the same command again, fitting only the units that are missing.

A file is written whole or not at all (a temporary file renamed over the old one), so a
kill mid-write leaves the previous state, never half a file. A kept result is reused
only when its fingerprint (the unit's files' contents and the fit options,
`unit.fingerprint`) is the unit's now: a unit whose files changed is fitted again. A
failed unit is kept too (its files would fail the same way), but only a failure of its
own data: a task that died with its worker is not the unit's verdict and is not kept.

The lot average's prediction of the unit is kept beside its fit, with the average it
was made with: a rerun whose lot average is the same does not simulate the unit again.
"""

from __future__ import annotations

import json
import os
import tempfile
from pathlib import Path

from analysis.lot.unit import UnitResult, UnitSpec

FORMAT = "isolator-lot-unit/1"
PREDICTION = "lot_average_prediction"


class UnitStore:
    """One JSON per unit in `directory` (created on the first write)."""

    def __init__(self, directory: Path) -> None:
        self.directory = Path(directory)

    def path(self, unit: str) -> Path:
        return self.directory / f"{unit}.json"

    def load(self, spec: UnitSpec) -> UnitResult | None:
        """The kept result of this unit, or None: none kept, unreadable, or made from
        other files or options."""
        doc = self._read(spec)
        if doc is None:
            return None
        try:
            return UnitResult.from_json(doc["unit"])
        except (KeyError, TypeError):  # a file of another version: fit again
            return None

    def prediction(self, spec: UnitSpec, average: dict[str, float]) -> dict | None:
        """The kept prediction of this unit by exactly this lot average, or None."""
        doc = self._read(spec)
        kept = (doc or {}).get(PREDICTION)
        if not kept or kept.get("average") != average:
            return None
        return kept["runs"]

    def save(self, result: UnitResult) -> None:
        self._write(result.unit, {"format": FORMAT, "unit": result.to_json()})

    def save_prediction(self, spec: UnitSpec, average: dict[str, float], runs: dict) -> None:
        doc = self._read(spec)
        if doc is None:  # nothing kept to attach it to
            return
        doc[PREDICTION] = {"average": average, "runs": runs}
        self._write(spec.name, doc)

    def _read(self, spec: UnitSpec) -> dict | None:
        try:
            doc = json.loads(self.path(spec.name).read_text(encoding="utf-8"))
        except (OSError, ValueError):  # absent, or not JSON (written by something else)
            return None
        if not isinstance(doc, dict) or doc.get("format") != FORMAT:
            return None
        unit = doc.get("unit")
        if not isinstance(unit, dict) or unit.get("fingerprint") != spec.fingerprint:
            return None
        return doc

    def _write(self, unit: str, doc: dict) -> None:
        self.directory.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{unit}.", suffix=".tmp", dir=self.directory)
        try:
            with os.fdopen(fd, "w", encoding="utf-8") as f:
                json.dump(doc, f, indent=1)
            os.replace(tmp, self.path(unit))
        except BaseException:
            Path(tmp).unlink(missing_ok=True)
            raise
