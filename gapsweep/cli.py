"""Command-line interface (thin): ``gapsweep plan | run | jobs | status | merge | repair | submit | report | export |
demo``.

Exit codes: 0 success, 1 a task-independent error (a run that cannot start, a store that cannot be read or
merged, a write error, a missing optional dependency, an output that exists), 2 an invalid job spec or argument
(nothing is written), 3 a run in which every task failed, 4 ``status --finished`` of a store with pending
tasks, 5 a run that ended with some rows failed or left pending (no GPU left: docs/running.md), 130 / 143 a
run stopped by SIGINT / SIGTERM (recorded
as interrupted; finish it with --resume), 141 the reader of standard output went away (``gapsweep ... | head``).

The library logs through ``logging.getLogger("gapsweep")``; :func:`main` attaches one stderr handler to it
(``-v`` for debug messages, ``-q`` for warnings only) and prints the commands' own results on stdout.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import textwrap
from pathlib import Path
from typing import Any

DESCRIPTION = """\
gapsweep: mean gap and gap distribution between an elastic body and a rough surface, by GFMD, the field theory
and SDE / Fokker-Planck ensembles, over whole parameter grids (docs/model.md; job specs: docs/jobs.md).

  gapsweep demo                                   the paper's figure 2 and a gap distribution (minutes on 2 cores)
  gapsweep plan JOB.toml                          validate a job spec, count its tasks, estimate the cost
  gapsweep run JOB.toml --store OUT.h5            run it (under mpiexec: an MPI task farm)
  gapsweep jobs                                   the shipped job specs (gapsweep run fig2 --store OUT.h5)
  gapsweep submit JOB.toml OUT_DIR --shards N     run it on Slurm: N shards + a merge job (docs/running.md)
  gapsweep status OUT.h5                          counts, failures, the cost and time left
  gapsweep repair OUT.h5 [--job JOB.toml]         mend damaged attributes where every row verifies
  gapsweep report OUT.h5 --out DIR                figures, tables and (for the paper's sets) verdicts
  gapsweep export OUT.h5 --out OUT.nc             the store as netCDF4 (xarray, ncdump, ...)
"""
EPILOG = """\
Open MPI as root needs OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1, and more ranks than cores
OMPI_MCA_rmaps_base_oversubscribe=1 (docs/running.md). Exit codes: 0 ok, 1 error, 2 invalid spec or argument,
3 every task of a run failed, 5 a run left rows failed or pending (`gapsweep status STORE` lists them).
""" + "{docs}\n"
# The docs/*.md that the help names are the project's documentation, not installed with the package (issue 40:
# a wheel's help pointed to files its user does not have): every help that names one says where they are.
DOCS_NOTE = ("docs/NAME.md: the documentation in the docs/ folder of the project's source (its repository or "
             "source archive; a wheel does not install it).")
EPILOG = EPILOG.format(docs=textwrap.fill(DOCS_NOTE, 115))


def _parser() -> argparse.ArgumentParser:
    from gapsweep import __version__

    p = argparse.ArgumentParser(prog="gapsweep", description=DESCRIPTION, epilog=EPILOG,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"gapsweep {__version__}")
    g = p.add_mutually_exclusive_group()
    g.add_argument("-v", "--verbose", action="store_true", help="also log debug messages of the library")
    g.add_argument("-q", "--quiet", action="store_true", help="log only warnings and errors")
    sub = p.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("plan", help="validate a job spec, print its task count and cost estimate")
    s.add_argument("job", help="job spec (TOML, see docs/jobs.md), or the name of a shipped one (`gapsweep jobs`)")
    s.add_argument("--shard", help="i/n: plan only shard i of n")
    s.add_argument("--ranks", type=int, default=1, help="ranks for the wall-time estimate (default 1)")
    s.add_argument("--store", help="check that the store fits on the disk of this path")
    s.add_argument("--ranks-per-gpu", type=int, default=1, metavar="K",
                   help="ranks sharing one GPU, for the GPU-memory check (default 1)")

    s = sub.add_parser("run", help="run a job into a store (serial, or under mpiexec as an MPI task farm)")
    s.add_argument("job", nargs="+", help="job spec(s) (TOML) or shipped job names (`gapsweep jobs`); several run in "
                                          "one launch, through one farm (--farm), each into its own --store")
    s.add_argument("--store", required=True, action="append",
                   help="HDF5 store path ({i} and {n} are replaced by the shard); once per job, in order")
    s.add_argument("--resume", action="store_true", help="finish the pending tasks of an existing store")
    s.add_argument("--overwrite", action="store_true", help="replace an existing store")
    s.add_argument("--shard", help="i/n: run shard i of n (0-based), or 'slurm' (SLURM_ARRAY_TASK_ID/COUNT)")
    s.add_argument("--writer", choices=("auto", "mpio", "rank0"), default="auto",
                   help="auto: mpio when h5py has MPI, else rank 0 writes (env GAPSWEEP_WRITER overrides auto)")
    s.add_argument("--progress", choices=("auto", "bar", "log", "none"), default="auto",
                   help="auto: a bar on a terminal, log lines otherwise")
    s.add_argument("--coordinator-works", choices=("auto", "yes", "no"), default="auto",
                   help="whether MPI rank 0 also runs tasks (auto: when 4 ranks or fewer)")
    s.add_argument("--mpi", choices=("auto", "on", "off"), default="auto",
                   help="auto: use MPI when started by an MPI launcher")
    s.add_argument("--break-lease", action="store_true",
                   help="take over the store's lease from a run that is gone (killed, or on a lost node)")
    s.add_argument("--task-timeout", type=float, default=None, metavar="SECONDS",
                   help="record a task running longer than this as failed (timeout) and go on")
    s.add_argument("--batch", choices=("auto", "off", "all"), default="off",
                   help="GFMD chains solved side by side: off (default: one solve at a time, measured faster in "
                        "the sweep, docs/benchmarks.md), auto (GPU chains with n <= 1024) or all (CPU backends too)")
    s.add_argument("--ranks-per-gpu", type=int, default=None, metavar="K",
                   help="ranks of a node that share one GPU, 1-48 (default: up to 8 per GPU, "
                        "under CUDA MPS, which the run starts and stops itself where it may, else 1; ranks beyond "
                        "work CPU units)")
    s.add_argument("--farm", choices=("together", "each"), default="together",
                   help="several jobs: together (default: one farm runs the units of all, the longest first; every "
                        "store as from a run of its own) or each (one farm per job, one after the other)")
    s.add_argument("--lookahead", type=int, default=4, metavar="N",
                   help="GPU units a GPU worker holds beyond the one it runs; their surfaces are made on N host "
                        "threads while the GPU works (default 4; 0: none)")
    s.add_argument("--reuse", action="append", default=[], metavar="OTHER.h5",
                   help="copy the done rows of the same tasks (same task id) from another store instead of "
                        "running them, where their checksums verify (repeatable; the run record names the "
                        "sources); only rows computed by the current algorithm version of their method, with "
                        "their kept fields")
    s.add_argument("--reuse-older", action="store_true",
                   help="with --reuse: also copy rows computed by another (older or unknown) algorithm version of "
                        "their method; the run record and `gapsweep status` name them")

    s = sub.add_parser("jobs", help="list the job specs shipped with gapsweep (run one by name: gapsweep run fig2 ...)")
    s.add_argument("--path", metavar="NAME", help="print the path of the shipped spec NAME instead")

    s = sub.add_parser("status", help="summarise a running or finished store")
    s.add_argument("store", help="HDF5 store written by `gapsweep run`")
    s.add_argument("--finished", action="store_true",
                   help="only check that no task is pending: exit 0, or 4 with one line saying how many are and "
                        "how the last run ended (the Slurm merge job names unfinished shards with it)")
    s.add_argument("--json", action="store_true",
                   help="print counts, the cost left (core-hours, GPU-hours) and the time left as JSON")

    _submit_parser(sub)
    s = sub.add_parser("requeue", help="(used by the Slurm job scripts) requeue this job after the time-limit "
                                       "warning stopped its run, if allowed")
    s.add_argument("store", help="the store the job's run writes")
    s.add_argument("--max", type=int, default=3, help="requeue at most this many times (default 3)")
    s.add_argument("--job-id", default=None, help="the job (default: $SLURM_JOB_ID)")
    s.add_argument("--dry-run", action="store_true", help="only say what would be done")

    s = sub.add_parser("merge", help="merge shard stores of one job into one store")
    s.add_argument("shards", nargs="+", help="shard stores of one job (same spec)")
    s.add_argument("--out", required=True, help="merged store to write")
    s.add_argument("--overwrite", action="store_true", help="replace an existing --out")
    s.add_argument("--on-conflict", choices=("error", "first", "last"), default="error",
                   help="rows of one task with equal status and different results in two shards: refuse "
                        "(default) or keep the first / last shard's; a better status always wins (done > "
                        "not_converged > failed)")
    s.add_argument("--break-lease", action="store_true", help="take over the output's lease from a merge that is gone")
    s.add_argument("--skip-damaged", action="store_true",
                   help="merge without the shard rows whose checksum does not match (default: refuse)")

    s = sub.add_parser("repair", help="rebuild a store's damaged provenance attributes and restore its job spec "
                                      "attributes (--job) where every row verifies (docs/reliability.md)")
    s.add_argument("store", help="the store (HDF5)")
    s.add_argument("--job", default=None, help="the job spec the store was run from (needed where its spec text "
                                               "is damaged; every task row is checked against it)")
    s.add_argument("--break-lease", action="store_true", help="take over the store's lease from a process that is gone")

    s = sub.add_parser("report", help="figures, tables and verdicts from one or more stores (gapsweep.analysis)")
    s.add_argument("store", nargs="+", help="HDF5 stores; figures are chosen from their axes and methods")
    s.add_argument("--out", default="out/report", help="report folder (default: out/report)")
    s.add_argument("--overwrite", action="store_true", help="replace a report already in --out")

    s = sub.add_parser("export", help="write a store as a netCDF4 file that xarray and netCDF tools open")
    s.add_argument("store", help="HDF5 store written by `gapsweep run`")
    s.add_argument("--out", required=True, help="netCDF file to write (e.g. out/demo.nc)")
    s.add_argument("--skip-damaged", action="store_true",
                   help="export without the rows whose checksum does not match (default: refuse)")
    s.add_argument("--overwrite", action="store_true", help="replace an existing --out")

    s = sub.add_parser("demo", help="run the shipped demo job: GFMD vs field theory (figure 2) and a gap distribution")
    s.add_argument("--out", default="out", help="output directory (default: out)")
    s.add_argument("--job", default=None, help="job spec or shipped job name (default: the shipped demo)")
    s.add_argument("--theory-only", action="store_true", help="only the field-theory figure-2 table and figure")
    for sp in sub.choices.values():  # subcommands whose help names a docs/*.md say where the docs are
        if "docs/" in sp.format_help():
            sp.epilog = DOCS_NOTE
    return p


SUBMIT_OPTIONS = ("--shards", "--mpi", "--account", "--partition", "--mem", "--time", "--merge-time", "--setup",
                  "--max-running", "--requeue", "--signal-lead", "--force", "--dry-run")


def _submit_parser(sub: Any) -> None:
    s = sub.add_parser("submit", help="submit a job to Slurm: an array of shards and a merge job, or one MPI job")
    s.add_argument("job", help="job spec (TOML) or a shipped job's name (gapsweep jobs)")
    s.add_argument("out", help="output folder: the final store is OUT/<job file name>.h5")
    g = s.add_mutually_exclusive_group(required=True)
    g.add_argument("--shards", type=int, metavar="N", help="N shard jobs (job arrays) and a merge job")
    g.add_argument("--mpi", type=int, metavar="P", help="one MPI job of P ranks")
    for k, h in (("account", "sbatch --account (env GAPSWEEP_ACCOUNT)"),
                 ("partition", "sbatch --partition (env GAPSWEEP_PARTITION)"),
                 ("mem", "sbatch --mem per node, e.g. 4G (env GAPSWEEP_MEM)"),
                 ("time", "time limit of the run jobs (env GAPSWEEP_TIME; default the scripts' 04:00:00)"),
                 ("merge-time", "time limit of the merge job (env GAPSWEEP_MERGE_TIME; default 00:30:00)"),
                 ("setup", "shell code each job runs first: module load ...; source venv/bin/activate "
                           "(env GAPSWEEP_SETUP)")):
        s.add_argument(f"--{k}", default=None, help=h)
    s.add_argument("--max-running", type=int, metavar="K", help="at most K array tasks at a time (--array=...%%K)")
    s.add_argument("--requeue", type=int, default=3, metavar="K",
                   help="a run job stopped by its time limit requeues itself up to K times (default 3; 0: never)")
    s.add_argument("--signal-lead", type=int, default=300, metavar="S",
                   help="seconds before the time limit at which a run job stops and requeues (default 300)")
    s.add_argument("--force", action="store_true", help="submit even if jobs of this store are queued or running")
    s.add_argument("--dry-run", action="store_true", help="print the sbatch commands and job scripts, submit nothing")


def _setup_logging(verbose: bool, quiet: bool) -> None:
    """One stderr handler on the "gapsweep" logger (the library only logs; applications configure)."""
    log = logging.getLogger("gapsweep")
    log.setLevel(logging.DEBUG if verbose else logging.WARNING if quiet else logging.INFO)
    if not any(getattr(h, "_gapsweep_cli", False) for h in log.handlers):
        h = logging.StreamHandler(sys.stderr)
        h.setFormatter(logging.Formatter("gapsweep: %(message)s"))
        h._gapsweep_cli = True  # type: ignore[attr-defined]
        log.addHandler(h)


def main(argv: list[str] | None = None) -> int:
    from gapsweep.sweep import limits

    # signals from here on: recorded for a run (its Stop acts on them), raised for the other commands
    old = limits.install_early(defer_all=True)
    try:
        parser = _parser()
        args, unknown = parser.parse_known_args(argv)
        if unknown:
            allowed = f" (allowed options: {' '.join(SUBMIT_OPTIONS)})" if args.command == "submit" else ""
            parser.error(f"unrecognized arguments: {' '.join(unknown)}{allowed}")
        _setup_logging(args.verbose, args.quiet)
        code = _main(args)
    finally:
        limits.restore_early(old)
    from gapsweep.sweep import store

    if store.io_failed():  # HDF5 may crash in its exit handlers after a failed write: leave without them
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


def _main(args: argparse.Namespace) -> int:
    from gapsweep.core.extras import MissingExtraError
    from gapsweep.sweep import limits
    from gapsweep.sweep.limits import Interrupted
    from gapsweep.sweep.spec import SpecError

    try:
        # run/demo: a signal is recorded and the run's Stop adopts it (the store records the interruption);
        # merge, report, export...: raised at once, their clean-up removes temporary files and the lease
        limits.install_early(defer_all=args.command in ("run", "demo"))
        rc = _dispatch(args)
        sys.stdout.flush()  # a closed pipe shows here, not in the interpreter's exit
        late = limits.take_pending()  # a signal no run adopted (a run with nothing to do), or one swallowed
        if late is not None:           # inside HDF5 while the command went on to complete
            e = Interrupted(late)
            what = ("before its run started work; nothing was run" if args.command in ("run", "demo") else
                    "where it could not stop (inside HDF5); the command completed")
            print(f"gapsweep: {args.command} {e} {what}", file=sys.stderr)
            return e.exit_code
        return rc
    except BrokenPipeError:
        # The reader (e.g. `| head`) is gone: no traceback, no "Broken pipe" at exit.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 141
    except MissingExtraError as e:
        print(f"gapsweep: {e}", file=sys.stderr)
        return 1
    except Interrupted as e:
        limits.take_pending()  # reported here
        if args.command not in ("run", "demo"):
            what = "; its temporary files and lease removed, no output replaced" if args.command in (
                "merge", "report", "export") else ""
            print(f"gapsweep: {args.command} {e}{what}", file=sys.stderr)
            return e.exit_code
        c = e.counts
        print(f"gapsweep: run {e}: {c.get('done', 0)} done, {c.get('failed', 0)} failed, "
              f"{c.get('not_converged', 0)} not converged in this run; recorded as interrupted, finish with "
              "--resume", file=sys.stderr)
        return e.exit_code
    except KeyboardInterrupt:
        print("gapsweep: interrupted", file=sys.stderr)
        return 130
    except SpecError as e:
        print(f"gapsweep: invalid job spec: {e}", file=sys.stderr)
        return 2
    except ValueError as e:
        print(f"gapsweep: {e}", file=sys.stderr)
        return 2
    except (RuntimeError, FileNotFoundError, OSError) as e:
        print(f"gapsweep: {e}", file=sys.stderr)
        return 1


def _jobs(args: argparse.Namespace) -> int:
    from gapsweep import jobs

    if args.path:
        print(jobs.path(args.path))
        return 0
    width = max(len(n) for n in jobs.names())
    for n in jobs.names():
        print(f"{n:<{width}}  {jobs.describe(n)}")
    print(f"\n(gapsweep run NAME --store OUT.h5; the files: {jobs.path('demo').parent})")
    return 0


_READS = {"status": "store", "merge": "shards", "export": "store", "report": "store", "repair": "store"}


def _probe_stores(args: argparse.Namespace) -> None:
    """The stores a reading command opens, read first in a forked child (store.crash_probe): a store whose
    damaged HDF5 metadata crashes the library is one line and exit 1, not a segfault (issue 40 item 3)."""
    from gapsweep.sweep import store

    names = getattr(args, _READS.get(args.command, ""), None)
    for p in [names] if isinstance(names, str) else names or []:
        store.crash_probe(p)


def _dispatch(args: argparse.Namespace) -> int:
    _probe_stores(args)
    if args.command in ("plan", "run", "submit"):  # a job argument may be a shipped job's name (gapsweep jobs)
        from gapsweep import jobs

        args.job = [jobs.resolve(j) for j in args.job] if args.command == "run" else jobs.resolve(args.job)
    if args.command == "jobs":
        return _jobs(args)
    if args.command == "plan":
        from gapsweep.sweep import runner

        if args.ranks < 1:
            raise ValueError(f"--ranks: expected an integer >= 1, got {args.ranks}")
        print(runner.plan(args.job, runner.parse_shard(args.shard), args.ranks, store=args.store,
                          ranks_per_gpu=args.ranks_per_gpu))
        return 0
    if args.command == "run":
        return _run(args)
    if args.command == "status":
        return _status(args)
    if args.command in ("submit", "requeue"):
        return _slurm(args)
    if args.command == "merge":
        from gapsweep.sweep import merge

        counts = merge.merge(args.shards, args.out, overwrite=args.overwrite, on_conflict=args.on_conflict,
                             break_lease=args.break_lease, skip_damaged=args.skip_damaged)
        print(f"merged {len(args.shards)} shard(s) into {args.out}: "
              + ", ".join(f"{v} {k}" for k, v in counts.items()))
        return 0
    if args.command == "repair":
        from gapsweep.sweep import repair

        job = None
        if args.job:
            from gapsweep import jobs

            job = jobs.resolve(args.job)
        for line in repair.repair(args.store, job, break_lease=args.break_lease):
            print(f"repair {args.store}: {line}")
        return 0
    if args.command == "report":
        from gapsweep.analysis.report import main as report_main

        print(f"report: {report_main(args.store, args.out, overwrite=args.overwrite)}")
        return 0
    if args.command == "export":
        from gapsweep.sweep import dataset

        nc = dataset.export_netcdf(args.store, args.out, overwrite=args.overwrite, skip_damaged=args.skip_damaged)
        print(f"netCDF4: {nc}")
        return 0
    if args.command == "demo":
        return _demo(args)
    raise AssertionError(args.command)  # pragma: no cover


def _run(args: argparse.Namespace) -> int:
    """`gapsweep run`: the jobs of this launch, through one farm (``--farm together``) or one after the other."""
    from gapsweep.sweep import runner
    from gapsweep.sweep import spec as specmod

    if len(args.store) != len(args.job):
        raise ValueError(f"--store: give one store per job, in order ({len(args.job)} job(s), "
                         f"{len(args.store)} store(s))")
    if len(args.job) > 1:  # every spec is validated before the first job runs
        for job in args.job:
            specmod.load(job)
    from gapsweep.sweep import launch

    summaries = launch.run_jobs(
        args.job, args.store, farm=args.farm, resume=args.resume, overwrite=args.overwrite,
        shard=runner.parse_shard(args.shard), writer=args.writer, progress=args.progress,
        coordinator_works=args.coordinator_works, mpi=args.mpi, break_lease=args.break_lease,
        task_timeout=args.task_timeout, batch=args.batch, ranks_per_gpu=args.ranks_per_gpu,
        lookahead=args.lookahead, reuse=args.reuse, reuse_older=args.reuse_older)
    rc = 0
    for s in summaries:  # every job ran; the first non-zero code is returned
        if s["rank"] == 0 and args.progress != "none":
            print(f"{s['store']}: {s['mode']}, {s['todo']} of {s['tasks']} tasks run: {s['done']} done, "
                  f"{s['failed']} failed, {s['not_converged']} not converged"
                  + (f", {s['pending']} left pending" if s.get("pending") else ""))
        code = _run_code(s)
        rc = rc or code
    return rc


def _run_code(s: dict) -> int:
    """Exit code of one job's run (docs/running.md): 3 every task of the run failed, 5 rows failed or pending
    are left in the store, else 0; the rank-0 process says why in one line."""
    if s["todo"] and s["failed"] == s["todo"]:
        if s["rank"] == 0:
            print(f"gapsweep: every task of this run failed ({s['failed']}); see `gapsweep status "
                  f"{s['store']}`", file=sys.stderr)
        return 3
    if s.get("unfinished"):
        if s["rank"] == 0:
            failed = s["unfinished"] - s.get("pending", 0)
            print(f"gapsweep: store {s['store']}: {s['unfinished']} row(s) not done ({failed} failed, "
                  f"{s.get('pending', 0)} pending): `gapsweep status {s['store']}` lists them; --resume runs the "
                  "pending ones (exit 5)", file=sys.stderr)
        return 5
    return 0


def _status(args: argparse.Namespace) -> int:
    """``gapsweep status``: the store's summary and the cost left (``--json``: both as JSON; ``--finished``: the
    merge job's check). The cost left needs the store's spec; a store whose spec no longer loads (a moved height
    map) still gets its summary, with the reason instead of the cost."""
    from gapsweep.sweep import costleft, store
    from gapsweep.sweep.schema import StoreError
    from gapsweep.sweep.spec import SpecError

    if args.finished:
        return _finished(args.store)
    if args.json:
        print(json.dumps(costleft.summary(args.store), indent=1, sort_keys=True, default=str))
        return 0
    print(store.status(args.store))
    try:
        print("\n".join(costleft.describe(costleft.cost_left(args.store))))
    except (SpecError, OSError, StoreError) as e:  # e.g. a damaged /tasks, which the summary names
        print(f"cost left: unknown ({e})")
    return 0


def _slurm(args: argparse.Namespace) -> int:
    from gapsweep.sweep import slurm

    if args.command == "requeue":
        ok, why = slurm.requeue(args.store, args.max, args.job_id, act=not args.dry_run)
        print(f"gapsweep requeue {args.store}: {'yes' if ok else 'no'}: {why}", file=sys.stderr)
        return 0 if ok else 1
    site = slurm.SiteOptions.from_env(account=args.account, partition=args.partition, mem=args.mem,
                                      time=args.time, merge_time=args.merge_time, setup=args.setup)
    sub = slurm.submit(args.job, args.out, shards=args.shards, mpi=args.mpi, site=site,
                       max_running=args.max_running, requeue_max=args.requeue, signal_lead=args.signal_lead,
                       force=args.force, dry_run=args.dry_run)
    if args.dry_run:
        print(sub.dry_run_text())
        return 0
    for n in sub.notes:
        print(f"gapsweep: {n}", file=sys.stderr)
    print(sub.summary())
    return 0


def _finished(path: str) -> int:
    """``status --finished``: 0 when every task of the store has a finished row, else 4 and one line naming the
    store, the pending count and how its last run ended (interrupted by a signal, stopped by an error, or
    still running / killed)."""
    from gapsweep.sweep import store

    df = store.read(path)
    pending = int((df.status == "pending").sum())
    if not pending:
        return 0
    from gapsweep.sweep.storecheck import run_records

    runs = run_records(store.read_attrs(path).get("runs", "[]"))
    last = runs[-1] if runs else {}
    how = (f"interrupted by {last['interrupted']}" if last.get("interrupted") else
           f"stopped: {last['stopped']}" if last.get("stopped") else
           "finished" if last.get("finished") else "never finished (killed, or still running)")
    print(f"gapsweep: store {path}: {pending} of {len(df)} tasks pending; its last run {how}", file=sys.stderr)
    return 4


def _demo(args: argparse.Namespace) -> int:
    from gapsweep import demo

    out = Path(args.out)
    if args.theory_only:
        print(demo.fig2_theory(out))
        print(f"figure: {out / 'fig2_theory.png'}")
        return 0
    from gapsweep import jobs

    job = jobs.resolve(args.job) if args.job else jobs.path("demo")
    res = demo.run(job, out)
    print(res["status"])
    if res["table"]:
        print("\nmean gap / h_rms by method (done tasks, averaged over seeds):")
        print(res["table"])
    print(f"\nstore: {res['store']}   (gapsweep status {res['store']}; gapsweep.store.read('{res['store']}'))")
    for f in res["figures"]:
        print(f"figure: {f}")
    return _run_code(res["summary"])  # rows failed or pending: not 0, as for `gapsweep run`


if __name__ == "__main__":
    sys.exit(main())
