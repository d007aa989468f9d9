#!/usr/bin/env bash
# Issue 38 on one GPU node (4 H200; runs needing more GPUs than the node has are skipped), about 7 minutes:
# the publication sweep (jobs/pub: fig2, fig3, fig4_5 in one launch, 1,632 rows), the four figure jobs and issue
# 38's own mixed sweep (benchmarks/jobs/issue38: exponential N = 1024/4096, hard wall, adhesion) in the layouts
# that matter, traced. From the repository root:
#   GAPSWEEP_COMMIT=$(git rev-parse HEAD) bash benchmarks/gpu_node_issue38.sh
# (OUT=folder, default benchmarks/results/farm/issue38; BUDGET=seconds after which no run starts, default 400.)
# Needs python3 with numpy, scipy, h5py, mpi4py, cupy (numba optional), Open MPI's mpiexec; CUDA MPS's
# nvidia-cuda-mps-control for the default layout (gapsweep starts and stops the daemon itself).
# Runs, in this order, while the budget lasts (SET@G:K[/each][/host]: G GPUs, K ranks per GPU, "auto" = gapsweep's
# default -- 8 per GPU --; "/each": the jobs of the launch one farm each, as before issue
# 38, else one farm for all of them, the default; "/host": the GPU tasks' surfaces made on the host, as before issue
# 38 -- GAPSWEEP_GPU_SURFACES=0 --, else on their GPU, the default):
#   pub@1:auto pub@4:auto pub@2:auto   the default (the first run is every later pub store's reference, bit for bit)
#   pub@4:auto/each                    the same layout, one farm per job: what the joint farm gains
#   pub@4:auto/host                    the same layout, surfaces on the host: what GPU surfaces gain (stores
#                                      round-off apart: compared by grid point within tolerance too)
#   pub@1:auto/host                    a second one-GPU layout for T1_best (the best one-GPU time, any layout: the
#                                      one-GPU probe: 8 per GPU best with GPU surfaces, one_gpu_probe.json)
#   figs@1:auto figs@4:auto            the four figure jobs (jobs/gpu) in one launch
#   mix@1:auto mix@4:auto              the mixed sweep (its one-GPU run is T1 and the reference)
#   mixsplit@4:auto                    the mixed sweep with split_chains = 2 (other task ids: compared by grid point,
#                                      within the solver's tolerance, in the JSON's "against_mix")
#   pub@4:12 pub@2:16 pub@1:16         48 MPS clients on 4 GPUs; 16 per GPU on 2; 16 per GPU on 1
# First the GPU test of the surfaces made on the GPU (tests/test_gpu_surfaces.py -m gpu, where pytest is installed).
# Each run: wall, start-up (launch -> farm start), efficiency T1_best / (k T_k), GPU utilisation (nvidia-smi every
# 0.5 s over the sweep, share of samples >= 80 %), the farms' trace (GAPSWEEP_TRACE: per-worker units, busy/idle,
# per farm start/first unit/last unit and the gaps between farms, coordinator latency, the longest units, the
# tail), CUDA contexts per process and GPU, stores compared with the set's reference. Writes OUT/gpu_node_issue38.json
# (everything, with a provenance record), .md (the table and the summary: T1_best, layouts tried, the default's
# efficiency, utilisation and idle share per GPU count), _runs.log (gapsweep's output), .log (this script's).
set -uo pipefail
OUT=${OUT:-benchmarks/results/farm/issue38}
mkdir -p "$OUT"
export NCCL_NVLS_ENABLE=0 OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 GAPSWEEP_FFT_THREADS=1
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
unset CUDA_VISIBLE_DEVICES
PY=${PYTHON:-python3}
WORK=${WORK:-/tmp/gapsweep_issue38}
rm -rf "$WORK"; mkdir -p "$WORK"
rm -f "$OUT/gpu_node_issue38_runs.log"  # the log of this call only
log="$OUT/gpu_node_issue38.log"
{
  date -u; hostname; nproc
  nvidia-smi --query-gpu=index,name,memory.total,driver_version --format=csv,noheader
  echo "mpiexec: $(command -v mpiexec) | MPS control: $(command -v nvidia-cuda-mps-control || echo none)"
  echo "MPS processes before: $(pgrep -a nvidia-cuda-mps || echo none)"
  $PY -c "import sys, cupy, mpi4py, h5py; print(sys.version.split()[0], 'cupy', cupy.__version__)"
  ngpu=$(nvidia-smi -L | grep -c '^GPU ')
  echo "GPUs: $ngpu"
  # the surfaces made on the GPU against the host's (seconds; needs pytest): a broken GPU path shows here first
  if $PY -c "import pytest" 2>/dev/null; then
    $PY -m pytest -q -p no:cacheprovider -m gpu tests/test_gpu_surfaces.py 2>&1 | tail -3
  else
    echo "pytest not installed: tests/test_gpu_surfaces.py -m gpu not run"
  fi
  $PY benchmarks/bench_multi_gpu.py --out "$OUT" --work "$WORK" --name gpu_node_issue38 --sets pub mix mixsplit figs \
    --max-gpus "$ngpu" --budget "${BUDGET:-400}" --launch-timeout 200 \
    --layouts pub@1:auto pub@4:auto pub@2:auto pub@4:auto/each pub@4:auto/host pub@1:auto/host \
    figs@1:auto figs@4:auto mix@1:auto mix@4:auto mixsplit@4:auto pub@4:12 pub@2:16 pub@1:16
  echo "bench exit: $?"
  echo "MPS processes after: $(pgrep -a nvidia-cuda-mps || echo none)"
  date -u
} 2>&1 | tee "$log"
rm -rf "$WORK"
