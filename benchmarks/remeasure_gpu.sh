#!/usr/bin/env bash
# Re-measure, at the current code, the GPU figures that README.md and docs/benchmarks*.md cite from result files
# measured before provenance records existed (issue 40 item 11). Run after the code freeze on a lent node of one
# NVIDIA H200 (the single-GPU steps) or four (all steps), from the repository root, with the code measured
# committed; about 7 minutes on 4 H200 (estimates per step below, from the legacy runs' own timings):
#   bash benchmarks/remeasure_gpu.sh
# Needs python3 with numpy, scipy, h5py, cupy (CUDA 13; the image's cupy-cuda13x), numba optional, and for the
# steps over several GPUs mpi4py with cupy's NCCL and Open MPI's mpiexec; no warp (the SDE step times the
# CUDA engine and the kernel limit without it). On a copy of the working tree without .git (a lent machine),
# pass the commit it is a copy of -- commit first, so that the copy is that commit -- and an OUT folder that
# comes back: the results go to their paths and into one archive $OUT/remeasure_gpu.tgz (with the log
# $OUT/remeasure_gpu.log), unpacked here from the repository root with `tar xzf DIR/remeasure_gpu.tgz`:
#   GAPSWEEP_COMMIT=$(git rev-parse HEAD) OUT=/some/dir bash benchmarks/remeasure_gpu.sh
# (expand $(git rev-parse HEAD) where the commit was made, before the command goes to the lent machine: there a
# .git of another commit may sit under the copied files; benchmarks/_record.py refuses a commit its .git knows
# whose code differs from the files measured)
# Steps (ONLY="..." picks some): gpu4096 limit hardwall sde cost_gpu (one GPU, ~4.5 min), challenge_x2
# (2 GPUs, ~1 min), challenge_x4 (4 GPUs, ~1.5 min).
# Then `python scripts/check_docs.py --debts` lists the numbers to update and the markers to drop (as for
# benchmarks/remeasure_cpu.sh).
set -uo pipefail
export NCCL_NVLS_ENABLE=0 TORCH_SYMM_MEM_DISABLE_MULTICAST=1 NVSHMEM_DISABLE_NVLS=1
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 GAPSWEEP_FFT_THREADS=1 PYTHONUNBUFFERED=1
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
PY=${PYTHON:-python3}
SCRATCH=$(mktemp -d /tmp/gapsweep_remeasure_gpu.XXXXXX)
ngpu=$(nvidia-smi -L 2>/dev/null | grep -c '^GPU ')
failed=0
KEPT=()
if [ "$(git rev-parse --show-toplevel 2>/dev/null)" != "$PWD" ]; then
  [[ "${GAPSWEEP_COMMIT:-}" =~ ^[0-9a-f]{40}$ ]] || { echo "not a git checkout: set GAPSWEEP_COMMIT to the 40-hex commit this tree is a copy of"; exit 2; }
  export GAPSWEEP_COMMIT
fi
if [ -n "${OUT:-}" ]; then mkdir -p "$OUT"; exec > >(tee "$OUT/remeasure_gpu.log") 2>&1; fi

keep() {  # keep SRC DST: the result and its sidecar record (a stale sidecar of DST removed)
  [ -s "$1" ] || { echo "missing or empty: $1"; failed=1; return 1; }
  cp "$1" "$2"
  KEPT+=("$2")
  if [ -f "$1.provenance.json" ]; then cp "$1.provenance.json" "$2.provenance.json"; KEPT+=("$2.provenance.json")
  else rm -f "$2.provenance.json"; fi
}

step() {  # step NAME COMMAND...: run, timed, logged; a failure is reported and the rest goes on;
          # ONLY="NAME ..." runs the steps named there alone
  local name=$1; shift
  if [ -n "${ONLY:-}" ] && [[ " $ONLY " != *" $name "* ]]; then echo "== $name: not in ONLY, skipped"; return 1; fi
  echo "== $name: $*"
  local t0=$SECONDS
  if "$@"; then echo "== $name: done in $((SECONDS - t0)) s"; else echo "== $name: FAILED"; failed=1; return 1; fi
}

date -u; hostname
nvidia-smi --query-gpu=index,name,memory.total,driver_version --format=csv,noheader
$PY -c "import sys, cupy; print(sys.version.split()[0], 'cupy', cupy.__version__)" || exit 1
echo "GPUs: $ngpu; mpiexec: $(command -v mpiexec || echo none)"
git diff --quiet HEAD -- gapsweep 2>/dev/null || echo "warning: gapsweep/ differs from HEAD (the records will say dirty)"

# README "On one H200: N = 4096 in 0.008-0.061 s (fields left on the GPU)", all 15+15 cases (~1 min)
step gpu4096 $PY benchmarks/bench_gfmd.py gpu --out "$SCRATCH/g" --n 4096 --all-cases &&
  keep "$SCRATCH/g/gpu.json" benchmarks/results/gfmd_limit/gpu4096_allcases_h200.json
# README "N = 16384 in 0.27 s (32 GB), N = 32768 in 1.25 s (129 GB)" (the memory part); docs/benchmarks.md
# "a force evaluation <= 1.5 FFT pairs" (the pairs per evaluation of whole solves); the legacy run's parts (~1.5 min)
step limit $PY benchmarks/bench_gfmd_limit.py --out "$SCRATCH/l" --tag new --parts surface pairs phases memory &&
  keep "$SCRATCH/l/new.json" benchmarks/results/gfmd_limit/new_h200.json
# README "hard wall 0.12-1.2 s at N = 4096 on an H200" (~20 s: 44 + 85 + 418 iterations, 4 solves each)
step hardwall $PY benchmarks/bench_contact.py gpu --out "$SCRATCH/cn" --n 4096 --sigma0 1e-3 1e-2 1e-1 --repeat 3 &&
  keep "$SCRATCH/cn/contact_gpu.json" benchmarks/results/gfmd_limit/hardwall_new_h200.json
# README "SDE: 10^7 realisations x 9,900 steps in 0.148 s ... 1.08x a plain cuRAND kernel"; docs/benchmarks.md
# "SDE on the GPU" (the user-call cases; the paper's Euler-Maruyama row needs warp and is left out) (~1 min)
step sde $PY benchmarks/bench_sde_gpu.py --out "$SCRATCH/sde" --limit &&
  { keep "$SCRATCH/sde/bench_sde_gpu.json" benchmarks/results/sde/bench_sde_gpu.json
    keep "$SCRATCH/sde/bench_sde_gpu.md" benchmarks/results/sde/bench_sde_gpu.md
    keep "$SCRATCH/sde/sde_kernel_limit.json" benchmarks/results/gfmd_limit/sde_kernel_limit.json
    keep "$SCRATCH/sde/sde_kernel_limit.md" benchmarks/results/gfmd_limit/sde_kernel_limit.md; }
# docs/benchmarks_gfmd.md "Cost of a force evaluation vs a bare FFT pair", GPU rows (~30 s)
step cost_gpu $PY benchmarks/bench_gfmd.py cost --out "$SCRATCH/cg" --n 2048 4096 8192 --backend cupy &&
  keep "$SCRATCH/cg/cost.json" benchmarks/results/gfmd/cost_gpu.json

if [ "$ngpu" -ge 2 ] && command -v mpiexec >/dev/null; then
  # README "74 evaluations of 32768^2 on two H200s" (coarse-to-fine start, the exponential law only) (~1 min)
  step challenge_x2 mpiexec -n 2 $PY benchmarks/bench_distributed.py --only-big --big 32768 --big-ranks 2 \
      --length 50 --big-laws exponential --out "$SCRATCH/challenge_32768_x2.json" &&
    keep "$SCRATCH/challenge_32768_x2.json" benchmarks/results/distributed/h200x2_challenge_32768.json
else
  echo "== challenge_x2: skipped (needs 2 GPUs and mpiexec)"
fi
if [ "$ngpu" -ge 4 ] && command -v mpiexec >/dev/null; then
  # README "65536^2 fits four H200s at 0.24 s per force evaluation": the exponential law, 150 evaluations at
  # most (the figure is the time per evaluation; the legacy run's 500 took 124 s) (~1.5 min)
  step challenge_x4 mpiexec -n 4 $PY benchmarks/bench_distributed.py --only-big --big-laws exponential \
      --big-iter 150 --out "$SCRATCH/h200x4_challenge.json" &&
    keep "$SCRATCH/h200x4_challenge.json" benchmarks/results/distributed/h200x4_challenge.json
else
  echo "== challenge_x4: skipped (needs 4 GPUs and mpiexec)"
fi

rm -rf "$SCRATCH"
if [ -n "${OUT:-}" ] && [ ${#KEPT[@]} -gt 0 ]; then tar czf "$OUT/remeasure_gpu.tgz" "${KEPT[@]}" && echo "archive: $OUT/remeasure_gpu.tgz (${#KEPT[@]} files)"; fi
echo "remeasure_gpu: $([ $failed = 0 ] && echo all steps run were done || echo SOME STEPS FAILED); next: python scripts/check_docs.py --debts"
exit $failed
