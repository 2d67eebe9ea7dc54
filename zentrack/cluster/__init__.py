"""Cluster tooling: what starts, records, deploys and soaks a run of separate processes (above the processes,
below the CLI). Five rooms, each importing only the rooms before it in this list:

- :mod:`.deployment`: the files that deploy a cluster elsewhere: compose and stack files, certificates;
- :mod:`.engines`: where a cluster runs besides this host's own processes: the Docker client, a swarm's nodes,
  network namespaces and the impaired links between them;
- :mod:`.recording`: the evaluator: every node's estimates or track lists recorded and judged into
  ``summary.json``, in a run's process or as ``zentrack record``;
- :mod:`.run`: one run on this host (``zentrack run``): its processes, flags and output folder, and ``zentrack
  status``/``health``;
- :mod:`.soak`: ``zentrack soak``: a run under a seeded schedule of faults on any engine, judged against a
  fault-free run.

What benches and commands share with them (tables, JSON reports, a run's summary table and closing line, free
ports) is in :mod:`zentrack.common`. Importing a room imports none of its modules.
"""
