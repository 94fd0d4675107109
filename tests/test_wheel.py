"""The wheel a user installs (README's main job: `pip install .`) holds the whole product.

The tests run an editable install (README), so no other test imports the built wheel:
a module or a data file the wheel left out would pass them all and fail at the bench.
"""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

pytestmark = pytest.mark.numeric  # times nothing: side by side on the cores (README)

ROOT = Path(__file__).parents[1]
PACKAGES = ("rig", "analysis", "sim")


def checkout_files() -> set[str]:
    """What the wheel must carry: every module and package file of the three packages
    (not caches), and data/ as rig/_data (pyproject's force-include, `rig.paths`)."""
    want = set()
    for pkg in PACKAGES:
        for f in (ROOT / pkg).rglob("*"):
            rel = f.relative_to(ROOT)
            if f.is_file() and "__pycache__" not in rel.parts and f.suffix not in (".pyc", ".nbi",
                                                                                   ".nbc"):
                want.add(rel.as_posix())
    for f in (ROOT / "data").rglob("*"):
        if f.is_file():
            want.add((Path("rig/_data") / f.relative_to(ROOT / "data")).as_posix())
    return want


def test_the_wheel_holds_every_module_and_the_data(tmp_path: Path) -> None:
    done = subprocess.run([sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps",
                           "-w", str(tmp_path), str(ROOT)], capture_output=True, text=True,
                          timeout=600, check=False)
    assert done.returncode == 0, done.stderr
    wheel = next(tmp_path.glob("isolator_rig-*.whl"))
    with zipfile.ZipFile(wheel) as z:
        held = set(z.namelist())
        # the console scripts README's commands call
        scripts = z.read(next(n for n in held if n.endswith("entry_points.txt"))).decode()
    missing = sorted(checkout_files() - held)
    assert not missing, f"left out of the wheel: {missing[:10]}"
    assert "rig/_data/table1.toml" in held and "rig/_data/profiles/A.toml" in held
    for script in ("rig = rig.cli:main", "analysis = analysis.cli:main", "sim = sim.cli:main"):
        assert script in scripts
