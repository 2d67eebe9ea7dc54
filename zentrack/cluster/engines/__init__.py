"""Where a cluster runs besides this host's own processes, and the levers on it: the Docker client
(:mod:`.docker`), a Docker Swarm's nodes and their drains (:mod:`.swarm`), and ``zentrack netns``: a compose
file's services each in a network namespace (:mod:`.netns`), with impaired links between two of them
(:mod:`.link_impair`). They know nothing of fault schedules or verdicts: the soak drives them."""
