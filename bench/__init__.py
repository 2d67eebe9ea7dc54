"""zentrack.bench: benchmarks run from the CLI (``zentrack bench ...``); each prints figures and writes JSON."""
