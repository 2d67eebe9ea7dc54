"""The Docker client as the soak's compose and stack backends and the swarm helpers call it: ``docker <args>``
with a clear error (:class:`DockerError`: the command and Docker's own words, or no client, or no answer), and
the check that the engine answers and the image was built before anything starts."""
from __future__ import annotations

import subprocess


class DockerError(RuntimeError):
    """A docker command failed; the message names the command and Docker's own words."""


def docker(*args: str, timeout: float = 120.0, check: bool = True, host: str | None = None,
           stderr_too: bool = False) -> str:
    """Run ``docker <args>`` (on the engine at ``host``, a DOCKER_HOST address; default: the client's own);
    its standard output, stripped (``stderr_too``: both streams as one, as ``docker logs`` splits a
    container's)."""
    try:
        done = subprocess.run(["docker", *(("-H", host) if host else ()), *args], text=True, timeout=timeout,
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT if stderr_too else subprocess.PIPE)
    except FileNotFoundError:
        raise DockerError("docker: no docker client on PATH (bash deploy/docker-test.sh installs the engine)") from None
    except subprocess.TimeoutExpired:
        raise DockerError(f"docker {' '.join(args[:3])}: no answer within {timeout:.0f} s") from None
    if check and done.returncode != 0:
        said = done.stdout if stderr_too else done.stderr
        raise DockerError(f"docker {' '.join(args[:4])}: {' '.join(said.split()) or f'exit {done.returncode}'}")
    return done.stdout.strip()


def check_image(image: str) -> None:
    """A clear error when the engine does not answer or the image was not built."""
    docker("info", "--format", "{{.ServerVersion}}", timeout=30)
    if subprocess.run(["docker", "image", "inspect", image], capture_output=True, timeout=30).returncode != 0:
        raise DockerError(f"image {image} not found: build it first (docker compose -f deploy/docker-compose.yml "
                          f"build, or bash deploy/docker-test.sh --keep-images)")
