# zentrack image: every service of deploy/docker-compose.yml runs a `zentrack` command from it.
#
#   docker compose -f deploy/docker-compose.yml up --build          (from the repository root)
#   docker build -t zentrack:latest .                               (the image alone)
#
# BASE_IMAGE: any Debian-like image with python3 (3.11 or newer) and its venv module; the default is the
# public python:3.11-slim. Where no registry can be reached, deploy/docker-test.sh makes a local base
# (debootstrap of Debian bookworm) and passes it here.
ARG BASE_IMAGE=python:3.11-slim
FROM ${BASE_IMAGE}

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1 \
    VIRTUAL_ENV=/opt/venv PATH=/opt/venv/bin:$PATH
# A virtual environment: Debian's system Python refuses `pip install` into the system (PEP 668)
RUN python3 -m venv /opt/venv && useradd --create-home --uid 10001 zentrack
WORKDIR /opt/zentrack

# Dependencies first, read from pyproject.toml: a change to the sources does not reinstall them
COPY pyproject.toml ./
RUN python3 -c "import tomllib; print('\n'.join(tomllib.load(open('pyproject.toml', 'rb'))['project']['dependencies']))" \
        > /tmp/requirements.txt \
    && pip install -r /tmp/requirements.txt && rm /tmp/requirements.txt

COPY README.md ./
COPY zentrack zentrack
COPY fusion fusion
COPY truth truth
COPY node node
COPY viewer viewer
COPY bench bench
COPY study study
COPY deploy/scenarios deploy/scenarios
RUN pip install --no-deps . && rm -rf build *.egg-info && mkdir -p /recordings && chown zentrack /recordings
# run from the user's home, not from the source tree: there the folder zentrack/ would shadow the installed
# package for `python -m zentrack` (how `zentrack run` starts its processes), and zentrack.node would be missing
WORKDIR /home/zentrack

USER zentrack
# NumPy's OpenBLAS would start a thread per core in every process, for matrix products far larger than a
# tracker's: a third of a restarted tracker's start-up CPU, which a loaded host gives out slowly (the soak sets
# the same for the processes it starts: zentrack/cluster/soak/lean_start.py)
ENV OPENBLAS_NUM_THREADS=1
# Healthy while this process's Zenoh liveliness token is visible (ZENTRACK_RUN/NAME/CONNECT/ZENOH_MODE come
# from the service's environment, see deploy/docker-compose.yml; the router service checks with --router).
# `zentrack health` imports only what it needs: about 0.25 s of CPU per check and container.
HEALTHCHECK --interval=10s --timeout=5s --start-period=30s --retries=3 CMD ["zentrack", "health"]
ENTRYPOINT []
CMD ["zentrack", "--help"]
