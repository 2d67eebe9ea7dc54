#!/usr/bin/env bash
# First command of the README: set up a virtual environment (once) and run the main job:
# a 10-tracker realtime cluster on seed 000 Experiment 2 (truth + 10 node processes over Zenoh on loopback,
# embedded default, no router), 300 steps at 10 Hz, then print the summary (also in out/quickstart/).
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/zentrack ]; then
    python3 -m venv .venv
    .venv/bin/python -m pip install --quiet --upgrade pip
    .venv/bin/python -m pip install --quiet -e .
fi
exec .venv/bin/zentrack run --scenario exp2 --nodes 10 --steps 300 --timing realtime --out out/quickstart "$@"
