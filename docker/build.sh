#!/bin/sh
# Build the URSA image without an image registry and without re-downloading torch:
#   1. the base image (URSA_BASE_IMAGE, default ursa-base:bookworm): used as is when present,
#      else built by docker/build-base.sh (mmdebstrap from this machine's apt sources) when it
#      is an ursa-base:* tag, else left to `docker build` to pull;
#   2. a wheelhouse of every pinned dependency (URSA_WHEELS_DIR, default
#      ~/.cache/ursa/docker-wheels, outside the repository): `pip download`ed once, re-downloaded
#      only when pyproject.toml's dependencies or docker/constraints.txt change;
#   3. `docker build` with that wheelhouse served on 127.0.0.1 (python3 -m http.server) and
#      reached through --network host, so the build itself needs no index.
# URSA_WHEELS=0 skips 2-3 (pip in the build then needs network access to its index).
#
#   docker/build.sh                                  # -> ursa:latest
#   URSA_IMAGE=ursa:dev URSA_BASE_IMAGE=python:3.11-slim-bookworm docker/build.sh
set -eu
cd "$(dirname "$0")/.."

IMAGE="${URSA_IMAGE:-ursa:latest}"
BASE="${URSA_BASE_IMAGE:-ursa-base:bookworm}"
WHEELS="${URSA_WHEELS:-1}"
WHEELS_DIR="${URSA_WHEELS_DIR:-${XDG_CACHE_HOME:-$HOME/.cache}/ursa/docker-wheels}"
WHEELS_PORT="${URSA_WHEELS_PORT:-38765}"   # fixed: the URL is part of the layer cache key
PY_VERSION="${URSA_PY_VERSION:-3.11}"      # the base image's Python (bookworm: 3.11)
PYTHON="${PYTHON:-python3}"

t0=$(date +%s)
if ! docker image inspect "$BASE" >/dev/null 2>&1; then
  case "$BASE" in
    ursa-base:*) URSA_BASE_IMAGE="$BASE" docker/build-base.sh ;;
    *) echo "base image $BASE is not here; docker build will try to pull it" ;;
  esac
fi

set -- --build-arg "BASE_IMAGE=$BASE"
server_pid=""
cleanup() { [ -z "$server_pid" ] || kill "$server_pid" 2>/dev/null || true; }
trap cleanup EXIT INT TERM

if [ "$WHEELS" = 1 ]; then
  mkdir -p "$WHEELS_DIR"
  reqs="$WHEELS_DIR/requirements.txt"
  "$PYTHON" docker/deps.py requirements > "$reqs.new"
  stamp=$(cat "$reqs.new" docker/constraints.txt | cksum | cut -d' ' -f1)
  if [ "$(cat "$WHEELS_DIR/.stamp" 2>/dev/null || true)" != "$stamp" ]; then
    echo "downloading the wheelhouse into $WHEELS_DIR"
    rm -f "$WHEELS_DIR/.stamp"
    # one retry, past pip's cache: a fresh clone's first build failed on a wheel whose hash did
    # not match (2026-12-03); the second try only fetches what is missing
    nocache=""
    for try in 1 2; do
      # shellcheck disable=SC2086
      if "$PYTHON" -m pip download --quiet --disable-pip-version-check $nocache -d "$WHEELS_DIR" \
          --only-binary=:all: --python-version "$PY_VERSION" --implementation cp \
          --abi "cp$(echo "$PY_VERSION" | tr -d .)" \
          -r "$reqs.new" -c docker/constraints.txt; then
        break
      fi
      [ "$try" = 2 ] && { echo "pip download failed twice" >&2; exit 1; }
      echo "pip download failed; retrying once without pip's cache"
      nocache="--no-cache-dir"
    done
    echo "$stamp" > "$WHEELS_DIR/.stamp"
  fi
  mv "$reqs.new" "$reqs"
  if "$PYTHON" -c "import socket,sys; s=socket.socket(); sys.exit(s.connect_ex(('127.0.0.1', $WHEELS_PORT)) != 0)"; then
    echo "port $WHEELS_PORT is taken; set URSA_WHEELS_PORT to a free one" >&2
    exit 1
  fi
  "$PYTHON" -m http.server --bind 127.0.0.1 --directory "$WHEELS_DIR" "$WHEELS_PORT" \
    >/dev/null 2>&1 &
  server_pid=$!
  i=0
  until "$PYTHON" -c "import socket; socket.create_connection(('127.0.0.1', $WHEELS_PORT), 1)" 2>/dev/null; do
    i=$((i + 1)); [ "$i" -lt 50 ] || { echo "wheelhouse server did not start" >&2; exit 1; }
    sleep 0.2
  done
  set -- "$@" --build-arg "WHEELS_URL=http://127.0.0.1:$WHEELS_PORT/"
fi

echo "building $IMAGE on $BASE"
docker build --network host "$@" -t "$IMAGE" .
echo "built $IMAGE in $(( $(date +%s) - t0 )) s:" \
  "$(docker image inspect --format '{{.Size}}' "$IMAGE" | awk '{printf "%.2f GB", $1/1e9}')"
