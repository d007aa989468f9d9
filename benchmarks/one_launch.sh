#!/usr/bin/env bash
# Issue 22 item 6 on one GPU node: the four figure jobs (jobs/gpu/fig6, fig4_5, fig2, fig3) in one launch against
# one launch each (same ranks, same GPU, CUDA MPS), their stores compared bit for bit; then the publication-scale
# sweep (jobs/pub/fig2, fig3, fig4_5: N = 4096, 16 seeds, 1,536 GFMD solves) in one launch on the one GPU.
#   bash benchmarks/one_launch.sh OUTDIR [RANKS=nproc] [RANKS_PER_GPU=1]      (MPS=1: with the CUDA MPS daemon)
# The farm's layout by default (docs/running.md, "Which layout"): one GPU worker per visible GPU, the other ranks
# CPU workers, no MPS. The issue-22 layout was RANKS=16 RANKS_PER_GPU=8 MPS=1.
# From the repository root with cupy, mpi4py, h5py installed. Writes OUTDIR/one_launch.txt.
set -uo pipefail
out=$1; ranks=${2:-$(nproc)}; k=${3:-1}; mkdir -p "$out"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 GAPSWEEP_FFT_THREADS=1
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
PY=${PYTHON:-python3}
work=${WORK:-/tmp/one_launch}; rm -rf "$work"; mkdir -p "$work/sep" "$work/one" "$work/pub"
now() { date +%s.%N; }
since() { $PY -c "import sys; print(round($(now) - $1, 1))"; }
log="$out/one_launch.txt"
{
  nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader
  echo "ranks $ranks, ranks per GPU $k, $(nproc) cores"
  t0=$(now)
  $PY - <<'PY'
import cupy
from gapsweep import gfmd, sde
from gapsweep.surface import self_affine

h = cupy.asarray(self_affine(64, 0.3, lambda_l=0.25, lambda_s=4.0 / 64, seed=0))
gfmd.solve(h, sigma0=1e-2, gamma0=1e-3, rho=2e-2, backend="cupy", host=False)
sde.gap_histogram_counts(1e-2, hurst=0.3, h_rms=2.34e-3, rho=2e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3,
                         c2=1.0, n=1000, device="cuda", bins=16)
PY
  echo "kernel compile (once per node): $(since "$t0") s"
  if [ "${MPS:-0}" = 1 ]; then
    export CUDA_MPS_PIPE_DIRECTORY=$work/mps CUDA_MPS_LOG_DIRECTORY=$work/mpslog
    mkdir -p "$CUDA_MPS_PIPE_DIRECTORY" "$CUDA_MPS_LOG_DIRECTORY"
    nvidia-cuda-mps-control -d && echo "MPS daemon started"
  fi
  jobs=(fig6 fig4_5 fig2 fig3)
  t_all=$(now)
  for j in "${jobs[@]}"; do
    t0=$(now)
    mpiexec -n "$ranks" --bind-to none $PY -m gapsweep -q run "jobs/gpu/$j.toml" --store "$work/sep/$j.h5" --ranks-per-gpu "$k" \
      --progress none
    echo "separate launch $j: rc $? $(since "$t0") s"
  done
  echo "separate launches, all four: $(since "$t_all") s"
  args=(); stores=()
  for j in "${jobs[@]}"; do args+=("jobs/gpu/$j.toml"); stores+=(--store "$work/one/$j.h5"); done
  t0=$(now)
  mpiexec -n "$ranks" --bind-to none $PY -m gapsweep -q run "${args[@]}" "${stores[@]}" --ranks-per-gpu "$k" --progress none
  echo "one launch, all four: rc $? $(since "$t0") s"
  $PY - "$work" <<'PY'
import sys
from gapsweep import store
w = sys.argv[1]
for j in ("fig6", "fig4_5", "fig2", "fig3"):
    d = store.diff(f"{w}/sep/{j}.h5", f"{w}/one/{j}.h5")
    print(f"store {j}: one launch vs separate launch: {'identical' if not d else d[:3]}")
PY
  t0=$(now)
  timeout "${PUB_TIMEOUT:-360}" mpiexec -n "$ranks" --bind-to none $PY -m gapsweep -q run jobs/pub/fig2.toml jobs/pub/fig3.toml \
    jobs/pub/fig4_5.toml --store "$work/pub/fig2.h5" --store "$work/pub/fig3.h5" --store "$work/pub/fig4_5.h5" \
    --ranks-per-gpu "$k" --progress none
  echo "publication sweep, one launch: rc $? $(since "$t0") s"
  $PY - "$work" <<'PY'
import sys
from gapsweep import store
for j in ("fig2", "fig3", "fig4_5"):
    try:
        df = store.read(f"{sys.argv[1]}/pub/{j}.h5")
    except Exception as e:
        print(j, "no store:", e)
        continue
    g = df[df.method == "gfmd"]
    print(f"pub {j}: {dict(df.status.value_counts())}; GFMD {len(g)} solves, wall per solve median "
          f"{g.wall_time.median():.3f} s, max {g.wall_time.max():.3f} s, iterations median {g.iterations.median():.0f}")
PY
  if [ "${MPS:-0}" = 1 ]; then echo quit | nvidia-cuda-mps-control; fi
} 2>&1 | tee "$log"
