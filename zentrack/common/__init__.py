"""The lowest layer of shared plumbing: argparse value types, the limits they share with the scenario files, and
process helpers (no Zenoh, no scenarios)."""
