#!/usr/bin/env bash
# The paper's figure jobs (jobs/gpu/fig6, fig4_5, fig2, fig3: 3,116 tasks) on one GPU node under one or more
# settings, each timed end to end and its stores compared with the CPU stores (issue 14 item 6). From the
# repository root, gapsweep importable, cupy + mpi4py + h5py installed (warp and pyFFTW are not needed: the SDE
# runs on the CUDA engine, the CPU FFTs fall back to numpy). Writes under OUTDIR.
#   bash benchmarks/gpu_figs.sh OUTDIR CPU_STORES_TGZ SETTING...
# SETTING = NAME:RANKS:K[:mps] -- RANKS MPI ranks per job, K of them on the GPU (--ranks-per-gpu K), ":mps" with
# the CUDA MPS daemon running (the GPU ranks' kernels share the GPU instead of taking turns). Example:
#   bash benchmarks/gpu_figs.sh OUT docs/results/stores.tgz mps4:16:4:mps k4:16:4
# Before the first setting the GPU kernels are compiled once (NVRTC; cupy keeps them in its on-disk cache, so a
# node pays this once): timed apart, in OUTDIR/node.txt. A setting that would start after BUDGET_S seconds is
# skipped; each runs under SETTING_TIMEOUT seconds. Per setting OUTDIR/NAME.txt: the per-job wall times, the
# store comparison (benchmarks/compare_stores.py) and where the ranks spent their time (row wall times).
set -uo pipefail
out=$1; tgz=$2; shift 2; mkdir -p "$out"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 GAPSWEEP_FFT_THREADS=1
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
PY=${PYTHON:-python3}
work=${WORK:-/tmp/gpu_figs}; rm -rf "$work"; mkdir -p "$work/cpu"
t_start=$(date +%s)
{
  nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
  $PY -c "import os, sys, cupy; print('cores', len(os.sched_getaffinity(0)), 'python', sys.version.split()[0], \
'cupy', cupy.__version__)"
  mpiexec --version 2>&1 | head -1
  tar xzf "$tgz" -C "$work/cpu"
  t0=$(date +%s.%N)
  $PY - <<'PY'
import cupy
from gapsweep import gfmd, sde
from gapsweep.surface import self_affine

h = cupy.asarray(self_affine(64, 0.3, lambda_l=0.25, lambda_s=4.0 / 64, seed=0))
gfmd.solve(h, sigma0=1e-2, gamma0=1e-3, rho=2e-2, backend="cupy", host=False)
gfmd.solve_batch([gfmd.BatchProblem(heights=h, sigma0=s, gamma0=1e-3, rho=2e-2) for s in (1e-2, 1e-1)],
                 backend="cupy", host=False)
sde.gap_histogram_counts(1e-2, hurst=0.3, h_rms=2.34e-3, rho=2e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3,
                         c2=1.0, n=1000, device="cuda", bins=16)
PY
  echo "kernel compile (fresh machine, once): rc $? $($PY -c "import time; print(round(time.time() - $t0, 1))") s"
} 2>&1 | tee "$out/node.txt"

for s in "$@"; do
  IFS=: read -r name ranks k mps <<< "$s"
  f="$out/$name.txt"
  if (( $(date +%s) - t_start > ${BUDGET_S:-100000} )); then echo "skipped $s (budget)" | tee -a "$out/node.txt"; continue; fi
  if [[ "${mps:-}" == mps ]]; then
    export CUDA_MPS_PIPE_DIRECTORY=$work/mps CUDA_MPS_LOG_DIRECTORY=$work/mpslog
    mkdir -p "$CUDA_MPS_PIPE_DIRECTORY" "$CUDA_MPS_LOG_DIRECTORY"
    nvidia-cuda-mps-control -d && echo "MPS daemon started" | tee -a "$f"
  fi
  echo "== $s $(date +%T)" | tee -a "$f"
  timeout "${SETTING_TIMEOUT:-600}" $PY benchmarks/bench_multi_gpu.py --out "$work/$name" --gpus 1 \
    --jobs fig6 fig4_5 fig2 fig3 --ranks "$ranks" --ranks-per-gpu "$k" 2>&1 | tee -a "$f"
  echo "rc $?" | tee -a "$f"
  if [[ "${mps:-}" == mps ]]; then
    echo quit | nvidia-cuda-mps-control; unset CUDA_MPS_PIPE_DIRECTORY CUDA_MPS_LOG_DIRECTORY; sleep 1
  fi
  for j in fig6 fig4_5 fig2 fig3; do
    [[ -f "$work/$name/gpus1/$j.h5" ]] && $PY benchmarks/compare_stores.py "$work/$name/gpus1/$j.h5" "$work/cpu/$j.h5"
  done 2>&1 | tee -a "$f"
  $PY - "$work/$name/gpus1" <<'PY' 2>&1 | tee -a "$f"
# where the time went: per job the run record's span, and per rank the sum of its rows' wall times by method
import json, sys
from pathlib import Path
import h5py, numpy as np
from gapsweep import store
for j in ("fig6", "fig4_5", "fig2", "fig3"):
    p = Path(sys.argv[1]) / f"{j}.h5"
    if not p.exists():
        continue
    run = json.loads(store.read_attrs(p)["runs"])[-1]
    with h5py.File(p) as f:
        t, r = f["tasks"][...], f["results"][...]
    print(j, "record", {k: run.get(k) for k in ("started", "finished", "gpus", "batch_units", "sde_engine")})
    for rank in np.unique(r["rank"]):
        sel = r["rank"] == rank
        by = {m.decode(): round(float(r["wall_time"][sel & (t["method"] == m)].sum()), 2)
              for m in np.unique(t["method"][sel])}
        print(f"  rank {rank}: rows {int(sel.sum())}, row wall sum {r['wall_time'][sel].sum():.2f} s {by}")
PY
done
echo "== done $(date +%T), $(( $(date +%s) - t_start )) s" | tee -a "$out/node.txt"
