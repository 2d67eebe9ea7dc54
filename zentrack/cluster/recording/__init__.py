"""The evaluator of a run: one recorder core (:mod:`.core`: the session, the refusals, the step times, the
counters over restarts, :mod:`.counters`) holding a payload part, every node's posteriors (:mod:`.estimates`) or
track lists (:mod:`.track_lists`), recorded as any observer hears them, judged against the truth into
``summary.json`` and saved as ``estimates.npz`` / ``tracks.npz``; inside ``zentrack run`` and ``zentrack soak``,
or as a process of its own for clusters no orchestrator starts (``zentrack record``, :mod:`.record`)."""
