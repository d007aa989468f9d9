#!/bin/bash
# Submit a job spec to Slurm.
#
#   slurm/submit.sh JOB.toml OUT_DIR --shards N [site options]  # array of N shards + a merge job (afterany)
#   slurm/submit.sh JOB.toml OUT_DIR --mpi NTASKS [site options] # one MPI job of NTASKS ranks
#
# Site options (each also from an environment variable; unset = the cluster's default):
#   --account A      GAPSWEEP_ACCOUNT      sbatch --account
#   --partition P    GAPSWEEP_PARTITION    sbatch --partition
#   --mem M          GAPSWEEP_MEM          sbatch --mem (per node, e.g. 4G)
#   --time T         GAPSWEEP_TIME         time limit of the run jobs (default 04:00:00)
#   --merge-time T   GAPSWEEP_MERGE_TIME   time limit of the merge job (default 00:30:00)
#   --setup CODE     GAPSWEEP_SETUP        shell code run first in every job (module load ...; source venv/bin/activate)
# Any other sbatch options go in SBATCH_ARGS (e.g. SBATCH_ARGS="--qos=short --mail-type=FAIL").
# The merge runs after the array whatever became of it (afterany; --kill-on-invalid-dep=yes cancels it if the
# array is gone) and names missing or unfinished shards, exiting 1 (docs/running.md "Slurm").
# Prints the job ids; the final store is OUT_DIR/<job name>.h5 (see `gapsweep status`).
set -euo pipefail
usage() { sed -n '2,18p' "$0" >&2; exit 2; }
[ $# -ge 4 ] || usage
JOB=$1; OUT=$2; MODE=$3; N=$4
shift 4
ACCOUNT=${GAPSWEEP_ACCOUNT:-}; PARTITION=${GAPSWEEP_PARTITION:-}; MEM=${GAPSWEEP_MEM:-}
TIME=${GAPSWEEP_TIME:-}; MERGE_TIME=${GAPSWEEP_MERGE_TIME:-}; SETUP=${GAPSWEEP_SETUP:-}
while [ $# -gt 0 ]; do
  [ $# -ge 2 ] || { echo "submit.sh: $1 needs a value" >&2; exit 2; }
  case "$1" in
    --account) ACCOUNT=$2 ;;
    --partition) PARTITION=$2 ;;
    --mem) MEM=$2 ;;
    --time) TIME=$2 ;;
    --merge-time) MERGE_TIME=$2 ;;
    --setup) SETUP=$2 ;;
    *) echo "submit.sh: unknown option $1 (allowed: --account --partition --mem --time --merge-time --setup)" >&2
       exit 2 ;;
  esac
  shift 2
done
HERE=$(cd "$(dirname "$0")" && pwd)
[[ "$N" =~ ^[1-9][0-9]*$ ]] || { echo "submit.sh: N must be a positive integer, got $N" >&2; exit 2; }
NAME=$(basename "$JOB" .toml)
mkdir -p "$OUT"
if [ -n "$SETUP" ]; then  # the jobs inherit the environment (sbatch --export=ALL): they run it too
  export GAPSWEEP_SETUP=$SETUP
  set +u; eval "$SETUP" >&2; set -u
fi
if [ -z "${GAPSWEEP:-}" ]; then
  if [ -x .venv/bin/gapsweep ]; then GAPSWEEP=$PWD/.venv/bin/gapsweep; else GAPSWEEP=gapsweep; fi
fi
export GAPSWEEP
SITE=()
[ -z "$ACCOUNT" ] || SITE+=(--account="$ACCOUNT")
[ -z "$PARTITION" ] || SITE+=(--partition="$PARTITION")
[ -z "$MEM" ] || SITE+=(--mem="$MEM")
RUN_TIME=()
[ -z "$TIME" ] || RUN_TIME=(--time="$TIME")
MTIME=()
[ -z "$MERGE_TIME" ] || MTIME=(--time="$MERGE_TIME")
$GAPSWEEP plan "$JOB" >&2  # validates the spec before anything is queued
# shellcheck disable=SC2086
case "$MODE" in
  --shards)
    ARRAY=$(sbatch --parsable ${SBATCH_ARGS:-} ${SITE[@]+"${SITE[@]}"} ${RUN_TIME[@]+"${RUN_TIME[@]}"} --array=0-$((N - 1)) \
      --output="$OUT/$NAME.shard%a.out" "$HERE/array_job.sbatch" "$JOB" "$OUT/$NAME.shard{i}.h5")
    ARRAY=${ARRAY%%;*}
    MERGE=$(sbatch --parsable ${SBATCH_ARGS:-} ${SITE[@]+"${SITE[@]}"} ${MTIME[@]+"${MTIME[@]}"} --dependency=afterany:"$ARRAY" \
      --kill-on-invalid-dep=yes --output="$OUT/$NAME.merge.out" \
      "$HERE/merge_job.sbatch" "$OUT/$NAME.shard{i}.h5" "$N" "$OUT/$NAME.h5")
    MERGE=${MERGE%%;*}
    echo "array $ARRAY merge $MERGE store $OUT/$NAME.h5"
    ;;
  --mpi)
    MPI=$(sbatch --parsable ${SBATCH_ARGS:-} ${SITE[@]+"${SITE[@]}"} ${RUN_TIME[@]+"${RUN_TIME[@]}"} --ntasks="$N" \
      --output="$OUT/$NAME.mpi.out" "$HERE/mpi_job.sbatch" "$JOB" "$OUT/$NAME.h5")
    echo "mpi ${MPI%%;*} store $OUT/$NAME.h5"
    ;;
  *) usage ;;
esac
