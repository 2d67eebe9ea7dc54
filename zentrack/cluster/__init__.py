"""Cluster tooling: the orchestrator and its recorder, reports, status probes, compose files, network
namespaces and soak tests (above the processes, below the CLI)."""
