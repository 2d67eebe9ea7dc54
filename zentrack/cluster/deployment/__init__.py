"""The files that deploy a cluster: ``zentrack compose`` (the docker-compose file, :mod:`.compose`; ``--stack``:
the Docker Swarm stack file, :mod:`.stack`) and ``zentrack certs`` (a CA and a key and certificate per role for
secure mode, :mod:`.certs`). They write files and start nothing."""
