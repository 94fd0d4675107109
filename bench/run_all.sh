#!/usr/bin/env bash
# Runs every benchmark; each prints ratios against a baseline measured in the same run.
set -euo pipefail
cd "$(dirname "$0")/.."
for b in bench/simulate.py bench/jacobian.py bench/identify.py bench/identify_many.py bench/acquisition.py bench/loop.py bench/tui.py bench/design.py; do
  echo "== $b"
  python "$b"
done
