#!/usr/bin/env bash
# Runs on a 16-core NVIDIA GPU node (H100/H200) from the repository root, with gapsweep importable
# (PYTHONPATH=$PWD or installed) and warp-lang, cupy, mpi4py, h5py present. Writes under OUTDIR.
#   bash benchmarks/gpu_node.sh sde     OUTDIR   # SDE GPU benchmark (10^7 x 9,900 steps and variants)
#   bash benchmarks/gpu_node.sh scaling OUTDIR   # GFMD sweep N=1024 on 1,2,4,8,16 ranks (CPU, one thread each)
#   bash benchmarks/gpu_node.sh figures OUTDIR   # the full figure jobs (16 ranks) into OUTDIR/*.h5
#   bash benchmarks/gpu_node.sh sde_gpus OUTDIR  # SDE sweep on 1 GPU vs one rank per GPU (all GPUs)
set -euo pipefail
what=$1; out=$2; mkdir -p "$out"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 PYTHONUNBUFFERED=1
export OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 GAPSWEEP_FFT_THREADS=1
nvidia-smi --query-gpu=name,driver_version --format=csv,noheader > "$out/gpu.txt" 2>&1 || true
case $what in
  sde)
    python benchmarks/bench_sde_gpu.py --out "$out/sde_gpu" ;;
  scaling)
    python benchmarks/bench_sweep_scaling.py --out "$out/scaling" --ranks 1 2 4 8 16 --n 1024 --seeds "${SEEDS:-24}" ;;
  figures)
    for j in ${JOBS:-fig6 fig4_5 fig2 fig3}; do
      echo "== $j $(date +%T)"
      mpiexec -n "${RANKS:-16}" --bind-to none python -m gapsweep run "jobs/$j.toml" --store "$out/$j.h5" \
        --resume --progress log
      python -m gapsweep status "$out/$j.h5" | tail -8
    done ;;
  sde_gpus)
    ngpu=$(nvidia-smi -L | grep -c '^GPU ')
    t0=$(date +%s.%N)
    CUDA_VISIBLE_DEVICES=0 python -m gapsweep run jobs/bench_sde_gpus.toml --store "$out/sde_1gpu.h5" --progress log
    t1=$(date +%s.%N)
    mpiexec -n "$ngpu" --bind-to none python -m gapsweep run jobs/bench_sde_gpus.toml --store "$out/sde_${ngpu}gpu.h5" \
      --progress log
    t2=$(date +%s.%N)
    python - "$out" "$ngpu" "$t0" "$t1" "$t2" <<'PY'
import sys
from gapsweep import store
out, n, t0, t1, t2 = sys.argv[1], int(sys.argv[2]), *map(float, sys.argv[3:])
d = store.diff(f"{out}/sde_1gpu.h5", f"{out}/sde_{n}gpu.h5")
w1, wn = t1 - t0, t2 - t1
print(f"| GPUs | wall [s] | speed-up | efficiency |\n| --- | --- | --- | --- |\n| 1 | {w1:.1f} | 1.00 | 100 % |")
print(f"| {n} | {wn:.1f} | {w1 / wn:.2f} | {100 * w1 / wn / n:.0f} % |")
print("stores identical:", not d, d[:3])
PY
    ;;
  *) echo "unknown: $what" >&2; exit 2 ;;
esac
