"""The lowest layer of shared plumbing: argparse value types and process helpers (no Zenoh, no scenarios)."""
