#!/bin/bash
# Thin wrapper of `gapsweep submit` (docs/running.md "Slurm"), kept for existing command lines:
#
#   slurm/submit.sh JOB.toml OUT_DIR --shards N [options]   is   gapsweep submit JOB.toml OUT_DIR --shards N [options]
#   slurm/submit.sh JOB.toml OUT_DIR --mpi NTASKS [options]  is   gapsweep submit JOB.toml OUT_DIR --mpi NTASKS [options]
#
# Options (see `gapsweep submit --help`): --account --partition --mem --time --merge-time --setup --max-running
# --requeue --signal-lead --force --dry-run. The site's setup code (--setup CODE, or GAPSWEEP_SETUP) is run here
# first, so that the gapsweep it activates is the one that submits.
set -euo pipefail
SETUP=${GAPSWEEP_SETUP:-}
prev=
for a in "$@"; do
  if [ "$prev" = --setup ]; then SETUP=$a; fi
  prev=$a
done
if [ -n "$SETUP" ]; then
  set +u; eval "$SETUP" >&2; set -u
fi
if [ -z "${GAPSWEEP:-}" ]; then
  if [ -x .venv/bin/gapsweep ]; then GAPSWEEP=$PWD/.venv/bin/gapsweep; else GAPSWEEP=gapsweep; fi
fi
export GAPSWEEP
# shellcheck disable=SC2086
exec $GAPSWEEP submit "$@"
