"""One run on this host: :class:`~.cluster.Cluster` starts the truth, the trackers (and a router, the viewer)
as processes, records them and stops them (:mod:`.cluster`); ``zentrack run``'s flags and closing verdict
(:mod:`.orchestrator`, :mod:`.options`); one live run per output folder (:mod:`.out_lock`); who is alive in a
run (``zentrack status`` and ``health``, :mod:`.status`: a container's health check, so it imports little)."""
