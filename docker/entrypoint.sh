#!/bin/sh
# Entry point of the URSA image: check the run directory, then run the role's command
# (compose.yaml gives each service its own, e.g. `python -m services.learner`).
set -eu
runs="${URSA_RUNS_DIR:-/runs}"
if ! mkdir -p "$runs" 2>/dev/null || ! [ -w "$runs" ]; then
  echo "ursa: run directory $runs is not writable by uid $(id -u); mount a volume owned by" \
       "uid 10001 (a new named volume is), or run with --user matching its owner" >&2
  exit 1
fi
[ "$#" -gt 0 ] || set -- python -m services.router
exec "$@"
