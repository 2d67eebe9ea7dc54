#!/usr/bin/env bash
# First command of the README: set up a virtual environment (once) and run the main job:
# seed 000 Experiment 2 (10 bearing-only trackers on a ring) with DTESKF beside DUKF, DESKF and DEKF.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/zentrack ]; then
    python3 -m venv .venv
    .venv/bin/python -m pip install --quiet --upgrade pip
    .venv/bin/python -m pip install --quiet -e .
fi
mkdir -p out
exec .venv/bin/zentrack sim --scenario exp2 --nodes 10 --runs 5 --filter dteskf,dukf,deskf,dekf,cteskf \
    --json out/quickstart.json "$@"
