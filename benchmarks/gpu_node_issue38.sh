#!/usr/bin/env bash
# Issue 38 on one GPU node (1, 2 or 4 GPUs; H200): the publication sweep (jobs/pub/fig2, fig3, fig4_5 in one launch,
# 1,632 rows) in the layouts that matter, traced, in about 8 minutes. From the repository root:
#   OUT=/some/dir bash benchmarks/gpu_node_issue38.sh        (BUDGET=seconds, default 400; GAPSWEEP_COMMIT=hash)
# Needs python3 with numpy, scipy, h5py, mpi4py, cupy (numba optional), Open MPI's mpiexec; CUDA MPS's
# nvidia-cuda-mps-control for the default layout (gapsweep starts and stops the daemon itself).
# Runs, in this order, as long as the budget lasts (G GPUs : K ranks per GPU, "auto" = gapsweep's default):
#   pub 1:auto  2:auto  4:auto   the default layout (the first run is every later store's reference, bit for bit)
#   pub 1:16                     a second one-GPU layout for T1_best (the best one-GPU time, any layout)
#   sde G:1 (G = all GPUs, >= 2) SDE job, no MPS: nvidia-smi lists each rank's contexts (item 4: own GPU only)
#   pub 4:1                      the layout before issue 38 (one GPU worker per GPU), for comparison
#   pub 4:12  2:16  1:1          48 MPS clients on 4 GPUs; 2 GPUs with 16 per GPU; the old one-GPU default
# Layouts with more GPUs than the node has are skipped. Each run: wall, start-up (launch -> farm start), efficiency
# T1_best / (k T_k), GPU utilisation (nvidia-smi every 0.5 s, whole run and sweep only, share of samples >= 80 %),
# the farm's trace (GAPSWEEP_TRACE: per-worker units, busy/idle, coordinator latency, the longest units, the tail),
# CUDA contexts per process and GPU (nvidia-smi --query-compute-apps), stores compared with the reference.
# Writes OUT/gpu_node_issue38.json (everything), .md (the table), _runs.log (gapsweep's output), .log (this).
set -uo pipefail
: "${OUT:?set OUT to the output folder}"
mkdir -p "$OUT"
export NCCL_NVLS_ENABLE=0 OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 GAPSWEEP_FFT_THREADS=1
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
unset CUDA_VISIBLE_DEVICES
PY=${PYTHON:-python3}
WORK=${WORK:-/tmp/gapsweep_issue38}
rm -rf "$WORK"; mkdir -p "$WORK"
log="$OUT/gpu_node_issue38.log"
{
  date -u; hostname; nproc
  nvidia-smi --query-gpu=index,name,memory.total,driver_version --format=csv,noheader
  echo "mpiexec: $(command -v mpiexec) | MPS control: $(command -v nvidia-cuda-mps-control || echo none)"
  echo "MPS processes before: $(pgrep -a nvidia-cuda-mps || echo none)"
  $PY -c "import sys, cupy, mpi4py, h5py; print(sys.version.split()[0], 'cupy', cupy.__version__)"
  ngpu=$(nvidia-smi -L | grep -c '^GPU ')
  echo "GPUs: $ngpu"
  $PY benchmarks/bench_multi_gpu.py --out "$OUT" --work "$WORK" --name gpu_node_issue38 --sets pub sde \
    --max-gpus "$ngpu" --budget "${BUDGET:-400}" --launch-timeout 240 \
    --layouts pub@1:auto pub@2:auto pub@4:auto pub@1:16 $([ "$ngpu" -ge 2 ] && echo "sde@$ngpu:1") pub@4:1 \
    pub@4:12 pub@2:16 pub@1:1
  echo "bench exit: $?"
  echo "MPS processes after: $(pgrep -a nvidia-cuda-mps || echo none)"
  date -u
} 2>&1 | tee "$log"
rm -rf "$WORK"
