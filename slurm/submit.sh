#!/bin/bash
# Submit a job spec to Slurm.
#
#   slurm/submit.sh JOB.toml OUT_DIR --shards N      # array of N shards + a merge job chained with afterok
#   slurm/submit.sh JOB.toml OUT_DIR --mpi NTASKS    # one MPI job of NTASKS ranks
#
# Extra sbatch options go in SBATCH_ARGS (e.g. SBATCH_ARGS="--partition=cpu --time=12:00:00").
# Prints the job ids; the final store is OUT_DIR/<job name>.h5 (see `gapsweep status`).
set -euo pipefail
usage() { sed -n '2,8p' "$0" >&2; exit 2; }
[ $# -eq 4 ] || usage
JOB=$1; OUT=$2; MODE=$3; N=$4
HERE=$(cd "$(dirname "$0")" && pwd)
[[ "$N" =~ ^[1-9][0-9]*$ ]] || { echo "submit.sh: N must be a positive integer, got $N" >&2; exit 2; }
NAME=$(basename "$JOB" .toml)
mkdir -p "$OUT"
if [ -z "${GAPSWEEP:-}" ]; then
  if [ -x .venv/bin/gapsweep ]; then GAPSWEEP=$PWD/.venv/bin/gapsweep; else GAPSWEEP=gapsweep; fi
fi
export GAPSWEEP
$GAPSWEEP plan "$JOB" >&2  # validates the spec before anything is queued
# shellcheck disable=SC2086
case "$MODE" in
  --shards)
    ARRAY=$(sbatch --parsable ${SBATCH_ARGS:-} --array=0-$((N - 1)) --output="$OUT/$NAME.shard%a.out" \
      "$HERE/array_job.sbatch" "$JOB" "$OUT/$NAME.shard{i}.h5")
    ARRAY=${ARRAY%%;*}
    MERGE=$(sbatch --parsable ${SBATCH_ARGS:-} --dependency=afterok:"$ARRAY" --output="$OUT/$NAME.merge.out" \
      "$HERE/merge_job.sbatch" "$OUT/$NAME.shard{i}.h5" "$N" "$OUT/$NAME.h5")
    MERGE=${MERGE%%;*}
    echo "array $ARRAY merge $MERGE store $OUT/$NAME.h5"
    ;;
  --mpi)
    MPI=$(sbatch --parsable ${SBATCH_ARGS:-} --ntasks="$N" --output="$OUT/$NAME.mpi.out" \
      "$HERE/mpi_job.sbatch" "$JOB" "$OUT/$NAME.h5")
    echo "mpi ${MPI%%;*} store $OUT/$NAME.h5"
    ;;
  *) usage ;;
esac
