# syntax=docker/dockerfile:1
# colonlight in a container: the HTTP service by default, the batch CLI with arguments, a Dask scheduler or worker
# with `--entrypoint dask` (see docker-compose.yml).
#
#   docker build -t colonlight .                                        # CPU-only torch (the default)
#   docker build --build-arg TORCH_VARIANT=cu128 -t colonlight:cu128 .  # a CUDA build of torch (run with --gpus all)
#   docker run --rm -p 8000:8000 -v colonlight-data:/data colonlight    # the API on http://localhost:8000
#   docker run --rm --user "$(id -u):$(id -g)" -v "$PWD":/data colonlight enhance /data/videos -o /data/out
#
# The install steps live in scripts/docker-steps.sh, which the tests also run in a fresh virtual environment.
FROM python:3.11-slim

# torch comes from the PyTorch wheel index of TORCH_VARIANT (cpu, cu126, cu128, ...) or any TORCH_INDEX given.
ARG TORCH_VERSION=2.13.0
ARG TORCH_VARIANT=cpu
ARG TORCH_INDEX=https://download.pytorch.org/whl/${TORCH_VARIANT}
# Extras of the package installed beside it: `cluster` (Dask distributed) lets the image run scheduler and workers.
ARG EXTRAS=cluster

LABEL org.opencontainers.image.title="colonlight" \
      org.opencontainers.image.description="Consistent lighting for colonoscopy video: batch CLI, HTTP service, Dask workers" \
      org.opencontainers.image.licenses="MIT"

ENV PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_ROOT_USER_ACTION=ignore \
    COLONLIGHT_DATA_DIR=/data/service

WORKDIR /src

# Dependencies first, from pyproject.toml alone: editing the source does not reinstall torch and the rest.
COPY --chmod=0755 scripts/docker-steps.sh /usr/local/bin/colonlight-docker-steps
COPY pyproject.toml ./
RUN TORCH_VERSION="${TORCH_VERSION}" TORCH_INDEX="${TORCH_INDEX}" EXTRAS="${EXTRAS}" colonlight-docker-steps deps

# Then the package, with its package data (the default weights in colonlight/weights/), and the non-root user.
COPY README.md LICENSE ./
COPY colonlight ./colonlight
COPY cli ./cli
COPY service ./service
RUN colonlight-docker-steps package \
    && APP_USER=colonlight APP_UID=10001 DATA_DIR=/data colonlight-docker-steps user \
    && rm -rf /src

# Numeric, so that a runtime such as Kubernetes can verify runAsNonRoot (the name is colonlight, made above).
USER 10001:10001
WORKDIR /data
VOLUME ["/data"]
EXPOSE 8000

# Liveness without curl: the image's own Python asks the service's /healthz.
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=4)"]

ENTRYPOINT ["colonlight"]
CMD ["serve", "--host", "0.0.0.0", "--port", "8000"]
