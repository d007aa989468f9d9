#!/usr/bin/env bash
# End to end on one GPU node (issue 14 item 6, issue 15's one-GPU part), from the repository root, gapsweep
# importable, cupy/mpi4py/h5py (+ warp-lang for the GPU tests) installed. Writes under OUTDIR.
#   bash benchmarks/gpu_e2e.sh OUTDIR [CPU_STORES_TGZ]
# 1. the paper's figure jobs (jobs/gpu/fig6, fig4_5, fig2, fig3: 3,116 tasks) with 16 ranks, K = ${K:-4} of them on
#    the GPU (benchmarks/bench_multi_gpu.py --gpus 1), stores compared with the CPU stores (compare_stores.py);
# 2. the GPU tests (scripts/test_gpu.sh);
# 3. 2 ranks on 1 GPU: --ranks-per-gpu 1 (rank 1 works CPU units) and 2 (they share it); 2 per-GPU shard stores
#    on the one GPU merged on the CPU: each store compared with the 16-rank fig6 store.
set -uo pipefail
out=$1; tgz=${2:-docs/results/stores.tgz}; mkdir -p "$out"
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
export PYTHONUNBUFFERED=1 OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 GAPSWEEP_FFT_THREADS=1
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
work=${WORK:-/tmp/gpu_e2e}; rm -rf "$work"; mkdir -p "$work/cpu"
nvidia-smi --query-gpu=name,driver_version,memory.total --format=csv,noheader | tee "$out/gpu.txt"
nproc | tee -a "$out/gpu.txt"
tar xzf "$tgz" -C "$work/cpu"

echo "== 1. figure jobs on one GPU $(date +%T)"
python benchmarks/bench_multi_gpu.py --out "$work/e2e" --gpus 1 --jobs fig6 fig4_5 fig2 fig3 --ranks 16 \
  --ranks-per-gpu "${K:-4}" --reference "$work/cpu" 2>&1 | tee "$out/e2e.txt"
cp "$work/e2e/runs.log" "$out/e2e_runs.log"
for j in fig6 fig4_5 fig2 fig3; do
  python benchmarks/compare_stores.py "$work/e2e/gpus1/$j.h5" "$work/cpu/$j.h5" --json "$work/cmp_$j.json"
  python -m gapsweep status "$work/e2e/gpus1/$j.h5" | tail -4
done 2>&1 | tee "$out/compare.md"
python - "$work" <<'PY' | tee -a "$out/compare.md"
import json, sys
from gapsweep import store
for j in ("fig6", "fig4_5", "fig2", "fig3"):
    runs = json.loads(store.read_attrs(f"{sys.argv[1]}/e2e/gpus1/{j}.h5")["runs"])[-1]
    print(j, {k: runs.get(k) for k in ("gpus", "gfmd_batch", "batch_units", "sde_engine", "started", "finished")})
PY

echo "== 2. GPU tests $(date +%T)"
timeout 240 bash scripts/test_gpu.sh -rA 2>&1 | tee "$out/tests.log" | tail -25

echo "== 3. 2 ranks on 1 GPU, shards $(date +%T)"
{
for k in 1 2; do
  t0=$(date +%s.%N)
  mpiexec -n 2 --bind-to none python -m gapsweep run jobs/gpu/fig6.toml --store "$work/fig6_2r_k$k.h5" \
    --ranks-per-gpu $k --progress none
  echo "2 ranks, --ranks-per-gpu $k: rc $? wall $(python -c "import time; print(round(time.time() - $t0, 1))") s"
done
python benchmarks/bench_multi_gpu.py --out "$work/shards" --gpus 2 --devices 0,0 --jobs fig6 --ranks 16 \
  --ranks-per-gpu 4 > /dev/null 2>&1
python - "$work" <<'PY'
import json, sys
import h5py, numpy as np
from gapsweep import store
w = sys.argv[1]
ref = f"{w}/e2e/gpus1/fig6.h5"
for s in (f"{w}/fig6_2r_k1.h5", f"{w}/fig6_2r_k2.h5", f"{w}/shards/gpus2/fig6.h5"):
    run = json.loads(store.read_attrs(s)["runs"])[-1]
    with h5py.File(s) as f:
        t, r = f["tasks"][...], f["results"][...]
    gpu_rows = {m.decode(): sorted(set(r["rank"][t["method"] == m].tolist())) for m in np.unique(t["method"])}
    print(s.split("/")[-1], "gpus", run.get("gpus"), "ranks per method", gpu_rows,
          "diff vs 16-rank store:", store.diff(s, ref)[:3] or "identical")
PY
} 2>&1 | tee "$out/two_ranks.txt"
cp "$work/e2e/results.json" "$out/e2e_results.json" 2>/dev/null
echo "== done $(date +%T)"
