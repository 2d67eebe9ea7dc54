#!/usr/bin/env bash
# First command of the README: set up a virtual environment (once) and run the main job:
# a 10-tracker realtime cluster on paper 0 Experiment 2 (truth + 10 node processes over Zenoh on loopback,
# embedded default, no router), 300 steps at 10 Hz, then print the summary (also in out/quickstart/).
# On a terminal the run draws a progress line; its last line says where the outputs are.
set -euo pipefail
cd "$(dirname "$0")/.."
if [ ! -x .venv/bin/zentrack ]; then
    echo "quickstart: setting up .venv (once; a minute or two)"
    python3 -m venv .venv
    .venv/bin/python -m pip install --quiet --upgrade pip
    # setuptools' note on every editable install (a folder named like the package may shadow it) is not for
    # a newcomer; any other warning still shows
    PYTHONWARNINGS="ignore:Editable installation" .venv/bin/python -m pip install --quiet -e .
fi
echo "quickstart: 10 trackers, 300 steps at 10 Hz (about 30 s); afterwards \`. .venv/bin/activate\` puts zentrack on PATH"
exec .venv/bin/zentrack run --scenario exp2 --nodes 10 --steps 300 --timing realtime --out out/quickstart "$@"
