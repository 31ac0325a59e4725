# syntax=docker/dockerfile:1
# The fogfleet operator image: slim, non-root (uid 65532), no writes outside /tmp, so it runs
# with readOnlyRootFilesystem and an emptyDir on /tmp (manifests/install, charts/fogfleet).
#   docker build -t ghcr.io/fogfleet/fogfleet:0.1.0 .
# Bump the Python patch release here (and prefer pinning the digest, @sha256:..., in CI).
ARG PYTHON_IMAGE=python:3.11.14-slim-bookworm

FROM ${PYTHON_IMAGE} AS build
ENV PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PYTHONDONTWRITEBYTECODE=1
RUN python -m venv /opt/fogfleet
WORKDIR /src
COPY pyproject.toml README.md ./
COPY operator/ operator/
# The runtime dependencies are pinned (==) in pyproject.toml; pip check fails on a conflict.
RUN /opt/fogfleet/bin/pip install --no-cache-dir . \
 && /opt/fogfleet/bin/pip check \
 && /opt/fogfleet/bin/python -m compileall -q /opt/fogfleet

FROM ${PYTHON_IMAGE}
LABEL org.opencontainers.image.title="fogfleet" \
      org.opencontainers.image.description="Kubernetes operator placing robot-fleet software modules on robot, edge and cloud nodes" \
      org.opencontainers.image.source="https://github.com/fogfleet/fogfleet" \
      org.opencontainers.image.licenses="Apache-2.0" \
      org.opencontainers.image.version="0.1.0"
RUN groupadd --system --gid 65532 fogfleet \
 && useradd --system --uid 65532 --gid 65532 --no-create-home --home-dir /nonexistent \
      --shell /usr/sbin/nologin fogfleet
COPY --from=build /opt/fogfleet /opt/fogfleet
# Nothing writes to the root filesystem: bytecode is precompiled, HOME and caches live in /tmp.
ENV PATH=/opt/fogfleet/bin:$PATH \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    HOME=/tmp \
    TMPDIR=/tmp \
    MPLCONFIGDIR=/tmp/matplotlib
USER 65532:65532
WORKDIR /tmp
# 8080: kopf liveness endpoint (/healthz); 9100: Prometheus metrics.
EXPOSE 8080 9100
ENTRYPOINT ["fogfleet"]
CMD ["run"]
