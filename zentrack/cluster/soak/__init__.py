"""``zentrack soak``: a run under a seeded schedule of faults, judged against the same run without them.

- the command and each run driven to its end: :mod:`.command`, :mod:`.drive`;
- the faults: each kind one entry of the fault registry, :mod:`.fault_kinds` (its undo, flag, target, length,
  limits, colour and backend verbs); the schedule, the plan and the windows, :mod:`.faults`;
- where the runs go and how a fault reaches a process (a backend's verbs), one backend per engine: :mod:`.backends`
  (loopback processes, network namespaces), :mod:`.compose_backend` (docker compose), :mod:`.stack_backend` (a swarm
  stack);
- the verdict: :mod:`.criteria`, :mod:`.accuracy` (accuracy per fault window), :mod:`.misses` (every deadline
  miss explained), :mod:`.usage` (RSS and CPU per process type), :mod:`.summary` and :mod:`.plot` (the
  figures), :mod:`.rejudge` (a finished soak judged again);
- a loaded host on purpose and the processes' share of it: :mod:`.cpu_hog`, :mod:`.priority`,
  :mod:`.lean_start`.
"""
