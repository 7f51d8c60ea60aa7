# URSA: one image for every role (router, repertoire, learner, collector, evaluator, dashboard,
# API); compose.yaml picks the role with each service's command. See docs/deploy.md.
#
#   docker build -t ursa:latest .                                   # public Python base, PyPI
#   docker/build.sh                                                 # local base + wheelhouse
#   docker build --build-arg BASE_IMAGE=ursa-base:bookworm \
#       --network host --build-arg WHEELS_URL=http://127.0.0.1:38765/ -t ursa:latest .
#
# Works with the classic builder and with BuildKit (no RUN --mount, no extra contexts).

# Any Debian-like image with python3 (3.11 or 3.12) and its venv module: the public
# python:*-slim images, or one built offline by docker/build-base.sh (ursa-base:bookworm).
ARG BASE_IMAGE=python:3.11-slim-bookworm

# --- the runtime requirements, read from pyproject.toml ---------------------------------------
# A separate stage, so the dependency layer below is keyed on the *list* of dependencies, not on
# the whole pyproject.toml: editing ruff or pytest settings does not reinstall torch.
FROM ${BASE_IMAGE} AS requirements
COPY pyproject.toml /src/pyproject.toml
COPY docker/deps.py /src/docker/deps.py
RUN python3 /src/docker/deps.py requirements /src/pyproject.toml > /requirements.txt

# --- the image ---------------------------------------------------------------------------------
FROM ${BASE_IMAGE}

# Everything but the two layers at the end is set up first: on an engine whose storage driver
# diffs layers naively (fuse-overlayfs, vfs), every step after the multi-GB dependency layer costs
# about a minute, so the project is one COPY after it, not COPY + pip install + metadata.
ENV VIRTUAL_ENV=/opt/venv \
    PATH=/opt/venv/bin:/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin \
    PYTHONPATH=/app \
    PYTHONPYCACHEPREFIX=/tmp/pycache \
    LANG=C.UTF-8 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_ROOT_USER_ACTION=ignore \
    URSA_RUNS_DIR=/runs \
    URSA_ROUTER=tcp/router:7447 \
    URSA_ROUTER_LISTEN=tcp/0.0.0.0:7447 \
    MPLCONFIGDIR=/tmp/matplotlib \
    NUMBA_CACHE_DIR=/tmp/numba

# A non-root user; /runs is the run-directory volume (a new named volume takes this owner).
RUN python3 -m venv "$VIRTUAL_ENV" \
 && groupadd --system --gid 10001 ursa \
 && useradd --system --uid 10001 --gid ursa --home-dir /home/ursa --create-home \
      --shell /usr/sbin/nologin ursa \
 && mkdir -p /runs \
 && chown ursa:ursa /runs
WORKDIR /home/ursa
EXPOSE 7447 8000 8080
ENTRYPOINT ["/bin/sh", "/app/docker/entrypoint.sh"]
CMD ["python", "-m", "services.router"]

# Pinned dependencies: direct ones from pyproject.toml, transitive ones from
# docker/constraints.txt (`make docker-lock`). This is the big layer (torch + CUDA libraries); it
# is rebuilt only when one of these two lists changes. Owned by root: services cannot modify it.
COPY --from=requirements /requirements.txt /opt/ursa/requirements.txt
COPY docker/constraints.txt /opt/ursa/constraints.txt
# Optional wheelhouse for offline/fast builds: a --find-links URL (docker/build.sh serves
# `pip download`ed wheels with `python3 -m http.server` on the host and builds with
# `--network host`). When set, pip uses only it (--no-index). Empty: wheels come from the package
# index pip is configured with (the build then needs network access).
ARG WHEELS_URL=
RUN set -eu; \
    if [ -n "$WHEELS_URL" ]; then set -- --no-index --find-links "$WHEELS_URL"; else set --; fi; \
    pip install "$@" --only-binary=:all: \
      -r /opt/ursa/requirements.txt -c /opt/ursa/constraints.txt; \
    pip check; \
    python -c "import torch, zenoh, pybullet, viser, fastapi, numba, mcap"

USER ursa

# The project (ursa, proto, services, docker/ helpers; .dockerignore is an allow-list), run from
# /app through PYTHONPATH (`python -m services.<role>`). A code change rebuilds only this layer.
COPY . /app
