# zentrack image: every service of deploy/docker-compose.yml runs a `zentrack` command from it.
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1 PIP_NO_CACHE_DIR=1
RUN useradd --create-home --uid 10001 zentrack
WORKDIR /opt/zentrack
COPY pyproject.toml README.md ./
COPY core core
COPY fusion fusion
COPY truth truth
COPY node node
COPY viewer viewer
COPY bench bench
COPY deploy/scenarios deploy/scenarios
RUN pip install . && mkdir -p /recordings && chown zentrack /recordings

USER zentrack
# Healthy while this process's Zenoh liveliness token is visible (ZENTRACK_RUN/NAME/CONNECT/MODE come
# from the service's environment, see deploy/docker-compose.yml).
HEALTHCHECK --interval=10s --timeout=8s --start-period=20s --retries=3 CMD ["zentrack", "health"]
ENTRYPOINT []
CMD ["zentrack", "--help"]
