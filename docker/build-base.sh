#!/bin/sh
# Build a local Debian base image with Python from this machine's own apt sources
# (mmdebstrap with no mirror argument reuses /etc/apt/sources.list*), then `docker import` it.
# Use it where no image registry can be reached:
#   docker/build-base.sh                      # builds ursa-base:bookworm unless it already exists
#   URSA_BASE_IMAGE=my/base:tag FORCE=1 docker/build-base.sh
#   docker build --build-arg BASE_IMAGE=ursa-base:bookworm -t ursa:latest .
# Needs root (or mmdebstrap's unshare mode) and mmdebstrap (apt-get install mmdebstrap).
set -eu

TAG="${URSA_BASE_IMAGE:-ursa-base:bookworm}"
SUITE="${URSA_BASE_SUITE:-bookworm}"   # bookworm ships Python 3.11, which the project supports
FORCE="${FORCE:-0}"

if [ "$FORCE" != 1 ] && docker image inspect "$TAG" >/dev/null 2>&1; then
  echo "base image $TAG exists (FORCE=1 rebuilds it)"
  exit 0
fi
command -v mmdebstrap >/dev/null 2>&1 || {
  if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "installing mmdebstrap (apt-get)"
    (apt-get update -qq || true)
    DEBIAN_FRONTEND=noninteractive apt-get install -y -qq mmdebstrap >/dev/null
  else
    echo "mmdebstrap is missing: apt-get install mmdebstrap" >&2; exit 1
  fi; }

# python3 + venv + certificates, and the few shared libraries manylinux wheels expect from the
# system (libgomp1, libquadmath0: torch, numpy/scipy); no docs, man pages or apt lists.
PACKAGES="python3,python3-venv,ca-certificates,libgomp1,libquadmath0"

echo "building base image $TAG from $SUITE ($PACKAGES)"
mmdebstrap --variant=minbase --components=main --include="$PACKAGES" \
  --aptopt='APT::Install-Recommends "false"' \
  --dpkgopt='path-exclude=/usr/share/man/*' \
  --dpkgopt='path-exclude=/usr/share/doc/*' \
  --dpkgopt='path-include=/usr/share/doc/*/copyright' \
  --dpkgopt='path-exclude=/usr/share/locale/*' \
  --dpkgopt='path-exclude=/usr/share/info/*' \
  --customize-hook='rm -rf "$1"/var/lib/apt/lists/* "$1"/var/cache/apt/*' \
  "$SUITE" - \
| docker import \
    --change 'ENV LANG=C.UTF-8' \
    --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
    --change 'CMD ["python3"]' \
    --message "mmdebstrap $SUITE minbase + $PACKAGES" \
    - "$TAG"
docker image inspect --format 'built {{.RepoTags}} {{.Size}} bytes' "$TAG"
