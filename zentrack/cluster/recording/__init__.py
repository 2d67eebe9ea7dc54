"""The evaluator of a run: every node's posteriors (:mod:`.recorder`) or track lists (:mod:`.mt_recorder`)
recorded as any observer hears them, judged against the truth into ``summary.json`` and saved as
``estimates.npz`` / ``tracks.npz``; inside ``zentrack run`` and ``zentrack soak``, or as a process of its own for
clusters no orchestrator starts (``zentrack record``, :mod:`.record`)."""
