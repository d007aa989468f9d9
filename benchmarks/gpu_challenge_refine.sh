#!/usr/bin/env bash
# The challenge's law on GPUs (issue 37 items 4-5; docs/challenge.md "Refinement study"): benchmarks/
# challenge_refine.py in stages that each fit a 10-minute call. From the repository root:
#   OUT=/some/dir STAGE=1 bash benchmarks/gpu_challenge_refine.sh
# Needs python3 with numpy, scipy, mpi4py, cupy (NCCL), Open MPI's mpiexec.
#   STAGE=1  one GPU: 4096 -> 8192 -> 16384 of a 25 um box (the finest pixel the challenge's 1.526 nm), 10 pairs,
#            the slab path on one rank (mpi4py present); each grid's memory pool against memory_plan
#   STAGE=2  four GPUs: 16384 -> 32768 of the challenge's 100 um box, 2 pairs, reference load along the path
#   STAGE=3  four GPUs: 65536^2 of the 100 um box, 2 pairs, the reference load from the flat body and +-5 %
#            (each solve's wall time is the time per load from the previous load's state)
# Each stage writes OUT/refine_stage<k>.json after every solve (a stage stopped by the time limit keeps what it
# measured) and OUT/refine_stage<k>.log.
set -uo pipefail
: "${OUT:?set OUT to the output folder}"
: "${STAGE:?set STAGE to 1, 2 or 3}"
mkdir -p "$OUT"
export NCCL_NVLS_ENABLE=0 OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
PY=${PYTHON:-python3}
LIMIT=${LIMIT:-560}  # seconds: below the 10-minute limit of one call, so that the log and JSON come back
log="$OUT/refine_stage$STAGE.log"
{ date -u; hostname; nvidia-smi --query-gpu=name,memory.total --format=csv,noheader; git rev-parse HEAD; } > "$log" 2>&1
case "$STAGE" in
  1) timeout "$LIMIT" $PY benchmarks/challenge_refine.py --gpu --n 4096 8192 16384 --box 25 --ramp 2 \
       --out "$OUT/refine_stage1.json" >> "$log" 2>&1 ;;
  2) timeout "$LIMIT" mpiexec -n 4 --bind-to none $PY benchmarks/challenge_refine.py --gpu --n 16384 32768 \
       --box 100 --pairs 2 --ramp 1 --out "$OUT/refine_stage2.json" >> "$log" 2>&1 ;;
  3) timeout "$LIMIT" mpiexec -n 4 --bind-to none $PY benchmarks/challenge_refine.py --gpu --n 65536 \
       --box 100 --pairs 2 --ramp 0 --out "$OUT/refine_stage3.json" >> "$log" 2>&1 ;;
  *) echo "STAGE must be 1, 2 or 3" >&2; exit 2 ;;
esac
rc=$?
echo "exit $rc" >> "$log"
tail -5 "$log"
exit $rc
