#!/usr/bin/env bash
# Re-measure, at the current code, the CPU figures that README.md and docs/benchmarks*.md cite from result files
# measured before provenance records existed (issue 40 item 11). Run after the code freeze, on the project's
# 2-core VM, from the repository root, with the code measured committed (the records name HEAD):
#   bash benchmarks/remeasure_cpu.sh              # about 11 minutes: targets, cost, checksums, sweep
#                                                 #   overhead, theory, vec, memory, Persson against converged GFMD
#   LONG=1 bash benchmarks/remeasure_cpu.sh       # + about 80 minutes: the ContactMechanics comparison, the
#                                                 #   held-out bounds, the cost-left estimate, the tuning set,
#                                                 #   the issue-39 hard wall against tamaas, the predictor
#                                                 #   studies of docs/theory.md, the challenge proxy and the
#                                                 #   leak-rate study (PEERS_PY: a python
#                                                 #   with ContactMechanics, Adhesion and tamaas, default
#                                                 #   /work/peers/bin/python; MPIEXEC: default mpiexec)
# Results cited with a provenance record that a code change made stale are listed by check_docs with the command
# that measured them (re-run those too; the issue-39 hard-wall step here is one of them).
# Each step writes into a scratch folder and copies its result over the cited file (with its provenance record:
# the JSON's "provenance" key or the sidecar FILE.provenance.json). Then:
#   python scripts/check_docs.py --debts
# lists every quoted number that no longer matches its (re-measured) file and every `<!-- remeasure: FILE -->`
# marker whose FILE now carries a record: update those numbers (the tables beside them from the .md the step
# wrote), drop the markers, commit the results. A step that fails leaves the cited file as it was.
# Times below: the legacy runs' own timings on the 2-core VM (one thread, shared).
set -uo pipefail
export OMP_NUM_THREADS=1 NUMBA_NUM_THREADS=1 OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 GAPSWEEP_FFT_THREADS=1
export PYTHONUNBUFFERED=1 PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
PY=${PYTHON:-python}  # the project's venv python, e.g. PYTHON=.venv/bin/python
PEERS_PY=${PEERS_PY:-/work/peers/bin/python}
MPIEXEC=${MPIEXEC:-mpiexec}  # Open MPI: 3 and 4 ranks on 2 cores need oversubscription (set below)
export OMPI_MCA_rmaps_base_oversubscribe=1 OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
SCRATCH=$(mktemp -d /tmp/gapsweep_remeasure_cpu.XXXXXX)
failed=0

keep() {  # keep SRC DST: the result and its sidecar record (a stale sidecar of DST removed)
  [ -s "$1" ] || { echo "missing or empty: $1"; failed=1; return 1; }
  cp "$1" "$2"
  if [ -f "$1.provenance.json" ]; then cp "$1.provenance.json" "$2.provenance.json"; else rm -f "$2.provenance.json"; fi
}

step() {  # step NAME COMMAND...: run, timed, logged; a failure is reported and the rest goes on;
          # ONLY="NAME ..." runs the steps named there alone
  local name=$1; shift
  if [ -n "${ONLY:-}" ] && [[ " $ONLY " != *" $name "* ]]; then echo "== $name: not in ONLY, skipped"; return 1; fi
  echo "== $name: $*"
  local t0=$SECONDS
  if "$@"; then echo "== $name: done in $((SECONDS - t0)) s"; else echo "== $name: FAILED"; failed=1; return 1; fi
}

git diff --quiet HEAD -- gapsweep || echo "warning: gapsweep/ has uncommitted changes (the records will say dirty)"

# README "GFMD: the fig2/fig3 cases at N = 2048 in 5-66 force evaluations"; docs/benchmarks_gfmd.md (~2 min)
step targets $PY benchmarks/bench_gfmd.py targets --out "$SCRATCH/targets" &&
  { keep "$SCRATCH/targets/targets.json" benchmarks/results/gfmd/targets.json
    keep "$SCRATCH/targets/targets.md" benchmarks/results/gfmd/targets.md; }

# docs/benchmarks_gfmd.md "Cost of a force evaluation vs a bare FFT pair", CPU rows (~1 min)
step cost_cpu $PY benchmarks/bench_gfmd.py cost --out "$SCRATCH/cost" --n 1024 2048 --backend pyfftw numpy &&
  keep "$SCRATCH/cost/cost.json" benchmarks/results/gfmd/cost_cpu.json

# README "Sweep: ... per task for a whole run of 4,000 field-theory tasks"; docs/benchmarks.md (~1 min: 24 runs
# of ~2 s); the result is the script's output, its record the first line
step checksum sh -c "$PY benchmarks/bench_checksum.py --pairs 12 > '$SCRATCH/bench_checksum.txt'" &&
  keep "$SCRATCH/bench_checksum.txt" benchmarks/results/round3/bench_checksum.txt

# docs/benchmarks.md "Sweep overhead" (an unsourced section until now: its raw output was not kept): 10^4
# theory tasks on 1 rank, then 2 and 4 MPI ranks (~1.5 min); it writes benchmarks/results/sweep/overhead.json
# and overhead.md (new files: then cite them there and drop that section's unsourced comment)
step overhead $PY benchmarks/bench_sweep_overhead.py --out "$SCRATCH/overhead" --mpi 2 4 &&
  { keep "$SCRATCH/overhead/overhead.json" benchmarks/results/sweep/overhead.json
    keep "$SCRATCH/overhead/overhead.md" benchmarks/results/sweep/overhead.md; }

# docs/theory.md "field theory on one core" (~30 s)
step theory $PY benchmarks/bench_theory.py --out "$SCRATCH/speed_vm.json" &&
  keep "$SCRATCH/speed_vm.json" benchmarks/results/theory/speed_vm.json

# docs/gfmd.md "CPU threads": BLAS against the single-threaded passes, idle and beside 2 busy processes (~1 min)
step vec env -u OPENBLAS_NUM_THREADS -u OMP_NUM_THREADS $PY benchmarks/bench_vec.py --load 0 2 --reps 10 --out "$SCRATCH/vec_2core.json" &&
  keep "$SCRATCH/vec_2core.json" benchmarks/results/vec/vec_2core.json

# docs/gfmd.md "One solve over several processes": memory per rank on 2 CPU ranks, and the in-place surface on
# 1-4 ranks (~1.5 min together)
step cpu_memory $MPIEXEC -n 2 $PY benchmarks/mem_distributed_cpu.py --out "$SCRATCH/cpu_memory.json" &&
  keep "$SCRATCH/cpu_memory.json" benchmarks/results/distributed/cpu_memory.json
step slab_surface sh -c "for P in 1 2 3 4; do $MPIEXEC -n \$P $PY benchmarks/mem_slab_surface.py --n 1024 --out '$SCRATCH/slab_surface_memory.json' || exit 1; done" &&
  keep "$SCRATCH/slab_surface_memory.json" benchmarks/results/distributed/slab_surface_memory.json

# docs/theory.md "Against converged hard-wall GFMD": Persson's area and gap against GFMD extrapolated in N (~1.3 min)
step persson_converged $PY -m studies.persson_converged --out "$SCRATCH/pc" &&
  { keep "$SCRATCH/pc/persson_converged.md" docs/results/persson_converged.md
    keep "$SCRATCH/pc/persson_converged.csv" docs/results/persson_converged.csv; }

if [ "${LONG:-0}" = 1 ]; then
  # docs/theory.md: the predictors against fresh GFMD on the held-out, fresh, large and tuning sets and the wider
  # grid (~3.1, 4.8, 3.0, 2.7 min and ~2 min)
  for set in heldout fresh large tuning; do
    step "predictors_$set" $PY -m studies.predictors_heldout --set $set --out "$SCRATCH/pred" &&
      { keep "$SCRATCH/pred/predictors_$set.md" "docs/results/predictors_$set.md"
        keep "$SCRATCH/pred/predictors_${set}_points.csv" "docs/results/predictors_${set}_points.csv"
        keep "$SCRATCH/pred/gap_distribution_$set.csv" "docs/results/gap_distribution_$set.csv"; }
  done
  # (the files above, spelt out for scripts/check_docs.py: docs/results/predictors_heldout.md,
  # docs/results/predictors_fresh.md, docs/results/predictors_large.md, docs/results/predictors_tuning.md)
  step predictors_wide $PY -m studies.predictors_wide --seeds 2 --out "$SCRATCH/pred" &&
    { keep "$SCRATCH/pred/predictors_wide.md" docs/results/predictors_wide.md
      keep "$SCRATCH/pred/predictors_wide.csv" docs/results/predictors_wide.csv; }
  # docs/gfmd.md, docs/gap_distribution.md, docs/benchmarks_gfmd.md, docs/benchmarks_sde.md: the solver error against
  # tol (CG, L-BFGS, FIRE) and the SDE's error against steps, cited by folder as benchmarks/results/claims_cpu/
  # (~3.6 min)
  step claims $PY benchmarks/bench_claims.py --out "$SCRATCH/claims" &&
    { keep "$SCRATCH/claims/bench_claims.json" benchmarks/results/claims_cpu/bench_claims.json
      keep "$SCRATCH/claims/bench_claims.md" benchmarks/results/claims_cpu/bench_claims.md; }
  # docs/benchmarks_gfmd.md "Speed against error": CG, L-BFGS and FIRE at tol 1e-3 .. 1e-8, n = 1024 and 2048
  # (~6 min: 4.9 min of solves in the legacy run, plus the references)
  step speed $PY benchmarks/bench_gfmd.py speed --out "$SCRATCH/speed" &&
    keep "$SCRATCH/speed/speed.json" benchmarks/results/gfmd/speed.json
  # docs/gfmd.md "Coarse-to-fine start": force evaluations of the plain and the coarse start on a CPU proxy of the
  # challenge, one core and 2 ranks (counts, not times; not timed before: the plain 4096^2 exponential solve on
  # one core takes longest, likely several minutes)
  step challenge_proxy $PY benchmarks/bench_challenge_proxy.py --case exp-1024 adh-1024 exp-2048-s2 adh-512-s2 \
      exp-4096 --out "$SCRATCH/challenge_proxy.json" &&
    keep "$SCRATCH/challenge_proxy.json" benchmarks/results/distributed/challenge_proxy.json
  step challenge_proxy_mpi2 $MPIEXEC -n 2 $PY benchmarks/bench_challenge_proxy.py --case exp-1024 adh-512-s2 \
      --out "$SCRATCH/challenge_proxy_mpi2.json" &&
    keep "$SCRATCH/challenge_proxy_mpi2.json" benchmarks/results/distributed/challenge_proxy_mpi2.json
  # docs/model.md "Leak rate against load": the shipped jobs leakage and leakage_measured, then the study
  # (a few minutes; not timed before)
  step leakage sh -c "$PY -m gapsweep run leakage --store '$SCRATCH/leak.h5' &&
      $PY -m gapsweep run leakage_measured --store '$SCRATCH/leak_measured.h5' &&
      $PY -m studies.leakage '$SCRATCH/leak.h5' '$SCRATCH/leak_measured.h5' --out '$SCRATCH/flow'" &&
    { keep "$SCRATCH/flow/leakage.csv" docs/results/flow/leakage.csv
      keep "$SCRATCH/flow/leakage.json" docs/results/flow/leakage.json
      keep "$SCRATCH/flow/leakage.png" docs/results/flow/leakage.png; }
  # docs/running.md "what a run still costs": the estimate after 15 s of jobs/demo.toml, then run to its end
  # (~2 min; the 45-s variant is history: the demo now ends within 45 s on this VM)
  step cost_left_15 $PY benchmarks/bench_cost_left.py --job jobs/demo.toml --stop-after 15 --out "$SCRATCH/demo.json" &&
    keep "$SCRATCH/demo.json" benchmarks/results/cost_left/demo.json
  # README "x-y times faster than ContactMechanics + Adhesion at N = 1024" (~7-11 min: the peer's L-BFGS-B)
  step peer env PEERS_PY="$PEERS_PY" $PY benchmarks/_peers_run.py benchmarks/bench_gfmd.py peer --out "$SCRATCH/peer" &&
    { keep "$SCRATCH/peer/peer.json" benchmarks/results/gfmd/peer.json
      keep "$SCRATCH/peer/peer.md" benchmarks/results/gfmd/peer.md; }
  # README "Hard wall: agrees with tamaas to < 1e-9 ... 8.0-19.0x less CPU time than tamaas on one core at
  # N = 1024 on 12 held-out cases" (~5 min, mostly tamaas; recorded at 56b6ea2: re-run when gapsweep/gfmd or
  # gapsweep/surfaces changed since, which check_docs reports as stale)
  step contact_issue39 env PEERS_PY="$PEERS_PY" $PY benchmarks/_peers_run.py benchmarks/bench_contact.py cpu --out "$SCRATCH/contact" \
      --n 1024 --hurst 0.4 0.8 --seeds 2 3 --sigma0 5e-3 1e-2 3e-2 --methods mpcg mpcg:restart --peers tamaas \
      --name issue39_contact_cpu_1024 &&
    { keep "$SCRATCH/contact/issue39_contact_cpu_1024.json" benchmarks/results/contact/issue39_contact_cpu_1024.json
      keep "$SCRATCH/contact/issue39_contact_cpu_1024.md" benchmarks/results/contact/issue39_contact_cpu_1024.md; }
  # README "an error estimate that bounded the error at 72 of 72 new held-out points", the multiscale gap
  # distribution's 34/36; docs/benchmarks*.md (~7 min: 5.7 min with cached GFMD references, which are re-solved here too:
  # their CPU seconds are the denominators of the cost ratios)
  step bounds_heldout $PY benchmarks/bench_bounds.py --set heldout --out "$SCRATCH/bounds" &&
    { keep "$SCRATCH/bounds/bounds_heldout.md" benchmarks/results/bounds/bounds_heldout.md
      keep "$SCRATCH/bounds/hybrid_heldout.csv" benchmarks/results/bounds/hybrid_heldout.csv
      keep "$SCRATCH/bounds/multiscale_heldout.csv" benchmarks/results/bounds/multiscale_heldout.csv
      keep "$SCRATCH/bounds/gfmd_heldout.json" benchmarks/results/bounds/gfmd_heldout.json; }
  # docs/theory.md "Issue 30 re-measurement" (the tuning set) and the constants chosen on its ladders
  # (~10 min: the tuning set's GFMD references re-solved, its ladders recorded, the choice replayed)
  step bounds_tuning sh -c "$PY benchmarks/bench_bounds.py --set tuning --out '$SCRATCH/tuning' &&
      $PY benchmarks/bench_bounds.py --set tuning --ladders --out '$SCRATCH/tuning' &&
      $PY benchmarks/bench_bounds.py --choose --out '$SCRATCH/tuning'" &&
    { keep "$SCRATCH/tuning/bounds_tuning.md" benchmarks/results/bounds/bounds_tuning.md
      keep "$SCRATCH/tuning/choose_tuning.csv" benchmarks/results/bounds/choose_tuning.csv; }
fi

rm -rf "$SCRATCH"
echo "remeasure_cpu: $([ $failed = 0 ] && echo all steps done || echo SOME STEPS FAILED); next: python scripts/check_docs.py --debts"
exit $failed
