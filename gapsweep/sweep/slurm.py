"""Submitting a job to Slurm (``gapsweep submit``; docs/running.md "Slurm").

* **Shards + merge**: ``--shards N`` submits job arrays of N shards in all (``slurm/array_job.sbatch``), each
  array throttled to ``--max-running K`` tasks at a time (``--array=0-M%K``) and no longer than the site's
  ``MaxArraySize`` (read from ``scontrol show config``; a longer sweep is split into several arrays whose
  indices stay below it, shard = offset + array index), and one merge job (``slurm/merge_job.sbatch``) that
  depends on all of them with ``afterany``. ``--mpi P`` submits one MPI job of P ranks instead.
* **Requeue**: the run jobs ask Slurm for ``SIGUSR1`` ``--signal-lead`` seconds before their time limit
  (``--signal=B:USR1@S``) and are submitted with ``--requeue``: the job script stops the run cleanly (the
  runner records it as interrupted) and calls :func:`requeue`, which requeues the job
  (``scontrol requeue $SLURM_JOB_ID``) unless it was requeued ``--requeue K`` times already or its last attempt
  finished no row (a progress file ``STORE.requeue`` beside the store keeps the count, keyed by the job id).
  A requeued job keeps its id and stays unfinished, so the merge's ``afterany`` waits for its last attempt
  (tests/test_slurm.py checks this on a real Slurm).
* **Never twice**: every job carries ``--comment=gapsweep:<key>[:<id>]``, the key being a hash of the final
  store's resolved path (``os.path.realpath``: ``./x/../out`` and a symlinked folder are the same store) and,
  when the store exists already, ``<id>`` a hash of its identity (device and inode: a hard link elsewhere is the
  same store too); a submission for a store with jobs still queued or running is refused, naming them, unless
  ``force``. When ``squeue`` cannot answer, nothing is submitted (unless ``force``): "0 queued" would be a guess.
* **Logs per attempt**: every job's ``--output`` names its job id (``%A``/``%j``) and is opened with
  ``--open-mode=append``, so a resubmission writes a new log and a requeued attempt (same id) appends to its
  earlier attempts' log after a header line naming the attempt (``SLURM_RESTART_COUNT``); a ``%`` of the output
  folder is escaped (``%%``) so that sbatch does not read it as a pattern.
* **MPI launcher**: ``--mpi P`` runs the ``mpiexec`` beside the submitting interpreter (a venv's own launcher,
  ``GAPSWEEP_MPIEXEC``) when there is one; otherwise the ``mpiexec`` on ``PATH`` must be of the MPI that mpi4py
  was built with (Open MPI / MPICH / Intel MPI), else the submission is refused naming both
  (``GAPSWEEP_LAUNCHER`` or ``--setup`` choose another).
* **Site limits**: ``MaxArraySize`` (above), ``MaxJobCount`` and, where ``sacctmgr`` can read it, the
  association's ``MaxSubmitJobs`` (per user) are checked before anything is submitted.

Everything Slurm is reached through its commands (``sbatch``, ``squeue``, ``scontrol``, ``sacctmgr``); no
command is run with ``dry_run``, which returns the commands and the job scripts instead.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shlex
import shutil
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

__all__ = ["QueueUnknown", "SiteOptions", "Submission", "comment", "existing_jobs", "requeue", "sbatch_escape",
           "site_limits", "store_identity", "store_key", "submit"]

log = logging.getLogger("gapsweep.slurm")

DEFAULT_MAX_ARRAY = 1001  # Slurm's default MaxArraySize (indices 0 .. 1000)
DEFAULT_LEAD = 300  # seconds between the warning signal and the time limit
REQUEUE_SUFFIX = ".requeue"


class SubmitError(RuntimeError):
    """A submission refused before anything was queued (a site limit, jobs of the store already queued)."""


@dataclass
class SiteOptions:
    """What differs between sites; each field also comes from an environment variable (the option wins)."""

    account: str = ""
    partition: str = ""
    mem: str = ""
    time: str = ""
    merge_time: str = ""
    setup: str = ""
    extra: list[str] = field(default_factory=list)  # SBATCH_ARGS

    @classmethod
    def from_env(cls, env: dict[str, str] | None = None, **given: Any) -> SiteOptions:
        env = os.environ if env is None else env
        kw = {k: (given.get(k) if given.get(k) is not None else env.get(f"GAPSWEEP_{k.upper()}", ""))
              for k in ("account", "partition", "mem", "time", "merge_time", "setup")}
        return cls(**kw, extra=shlex.split(env.get("SBATCH_ARGS", "")))

    def args(self, merge: bool = False) -> list[str]:
        out = list(self.extra)
        for k in ("account", "partition", "mem"):
            if getattr(self, k):
                out.append(f"--{k}={getattr(self, k)}")
        t = self.merge_time if merge else self.time
        if t:
            out.append(f"--time={t}")
        return out


@dataclass
class Submission:
    """What :func:`submit` did (or, with ``dry_run``, would do)."""

    store: Path
    key: str
    commands: list[list[str]] = field(default_factory=list)
    env: dict[str, str] = field(default_factory=dict)  # the variables the jobs get beyond the caller's
    scripts: dict[str, str] = field(default_factory=dict)
    arrays: list[str] = field(default_factory=list)
    merge: str = ""
    mpi: str = ""
    notes: list[str] = field(default_factory=list)

    def summary(self) -> str:
        if self.mpi:
            return f"mpi {self.mpi} store {self.store}"
        return f"array {','.join(self.arrays)} merge {self.merge} store {self.store}"

    def dry_run_text(self) -> str:
        env = " ".join(f"{k}={shlex.quote(v)}" for k, v in sorted(self.env.items()))
        lines = [f"# {n}" for n in self.notes]
        lines.append(f"# environment of the jobs (beyond the current one): {env}")
        for c in self.commands:
            lines.append(shlex.join(c))
        for name, text in self.scripts.items():
            lines.append(f"\n# ---- {name} ----\n{text.rstrip()}")
        return "\n".join(lines)


def scripts_dir() -> Path:
    """The job scripts, shipped in the package (``gapsweep/sweep/jobscripts``; ``slurm/`` of a checkout links to
    them), so that ``gapsweep submit`` works from an installed wheel too."""
    d = Path(__file__).resolve().parent / "jobscripts"
    if not (d / "array_job.sbatch").is_file():
        raise FileNotFoundError(f"the Slurm job scripts are not at {d}: the installation is incomplete "
                                "(reinstall gapsweep)")
    return d


def store_key(store: str | Path) -> str:
    """The key of a final store in the jobs' ``--comment`` (``gapsweep:<key>``): 16 hex digits of the SHA-256
    of its resolved path (``os.path.realpath``: ``..``, ``.`` and symlinks of the store or its folders
    resolved, whether or not the store exists yet)."""
    return hashlib.sha256(os.path.realpath(Path(store).absolute()).encode()).hexdigest()[:16]


def store_identity(store: str | Path) -> str | None:
    """16 hex digits of a hash of an existing store's identity (device and inode: the same file under any path,
    a hard link included); None when the store does not exist (yet)."""
    try:
        st = os.stat(store)
    except OSError:
        return None
    return hashlib.sha256(f"{st.st_dev}:{st.st_ino}".encode()).hexdigest()[:16]


def comment(key: str, ident: str | None) -> str:
    """The jobs' ``--comment``: ``gapsweep:<path key>`` and, for an existing store, ``:<identity>``."""
    return f"gapsweep:{key}" + (f":{ident}" if ident else "")


def _comment_keys(text: str) -> set[str]:
    """The keys a job's comment names (``gapsweep:<key>[:<identity>]``); empty for other comments."""
    text = text.strip()
    if not text.startswith("gapsweep:"):
        return set()
    return {k for k in text[len("gapsweep:"):].split(":") if k}


def sbatch_escape(path: str | Path) -> str:
    """A literal path in sbatch's ``--output`` (where ``%`` starts a pattern: ``%j``, ``%A``): every ``%`` doubled."""
    return str(path).replace("%", "%%")


def _cmd(args: list[str], timeout: float = 30) -> subprocess.CompletedProcess | None:
    """Run a Slurm command; None when it is not installed or does not answer."""
    if shutil.which(args[0]) is None:
        return None
    try:
        return subprocess.run(args, capture_output=True, text=True, timeout=timeout)
    except (OSError, subprocess.SubprocessError) as e:
        log.debug("%s: %s", args[0], e)
        return None


def _int(text: str | None) -> int | None:
    return int(text) if text and text.strip().isdigit() else None


def site_limits() -> dict[str, int | None]:
    """``MaxArraySize`` and ``MaxJobCount`` from ``scontrol show config``; ``MaxSubmitJobs`` of the user's
    association (``sacctmgr``, where accounting is configured). None: unknown."""
    out: dict[str, int | None] = {"MaxArraySize": None, "MaxJobCount": None, "MaxSubmitJobs": None}
    p = _cmd(["scontrol", "show", "config"])
    if p is not None and p.returncode == 0:
        for line in p.stdout.splitlines():
            k, _, v = line.partition("=")
            if k.strip() in ("MaxArraySize", "MaxJobCount"):
                out[k.strip()] = _int(v)
    user = os.environ.get("USER") or _whoami()
    p = _cmd(["sacctmgr", "-n", "-P", "show", "assoc", f"where user={user}", "format=MaxSubmit,GrpSubmit"], 15)
    if p is not None and p.returncode == 0:
        vals = [_int(x) for line in p.stdout.splitlines() for x in line.split("|")]
        vals = [v for v in vals if v is not None]
        out["MaxSubmitJobs"] = min(vals) if vals else None
    return out


def _whoami() -> str:
    import getpass

    try:
        return getpass.getuser()
    except (KeyError, OSError):  # pragma: no cover
        return str(os.getuid())


class QueueUnknown(SubmitError):
    """``squeue`` is missing or failed: whether jobs of the store are queued cannot be told."""


def existing_jobs(key: str, ident: str | None = None) -> list[str]:
    """Ids of the queued or running jobs whose comment names the store's path key ``key`` or its identity
    ``ident`` (:func:`comment`). Raises :class:`QueueUnknown` when ``squeue`` is missing, fails or times out."""
    p = _cmd(["squeue", "-h", "-o", "%i|%k|%T"])
    if p is None or p.returncode != 0:
        why = ("squeue is not installed here" if shutil.which("squeue") is None else
               "squeue did not answer" if p is None else
               f"squeue failed (exit {p.returncode}: {(p.stderr or p.stdout).strip()[:200]})")
        raise QueueUnknown(why)
    mine = {key} | ({ident} if ident else set())
    ids = []
    for line in p.stdout.splitlines():
        parts = line.strip().split("|")
        if len(parts) >= 2 and _comment_keys(parts[1]) & mine:
            ids.append(parts[0])
    return ids


def _user_jobs() -> int | None:
    """Jobs of this user in the queue, each array task counted (what MaxSubmitJobs counts)."""
    p = _cmd(["squeue", "-h", "-r", "-u", os.environ.get("USER") or _whoami(), "-o", "%i"])
    if p is None or p.returncode != 0:
        return None
    return len([x for x in p.stdout.splitlines() if x.strip()])


def split_array(n: int, max_array: int) -> list[tuple[int, int]]:
    """``(offset, count)`` of the arrays that hold ``n`` shards with every index below ``max_array``."""
    if n < 1 or max_array < 1:
        raise ValueError(f"split_array: n and max_array must be >= 1, got {n}, {max_array}")
    return [(o, min(max_array, n - o)) for o in range(0, n, max_array)]


def _check_limits(limits: dict[str, int | None], new_jobs: int) -> list[str]:
    """Refuse a submission beyond MaxSubmitJobs / MaxJobCount (SubmitError); notes about what was checked."""
    notes = []
    queued = _user_jobs()
    for name in ("MaxSubmitJobs", "MaxJobCount"):
        lim = limits.get(name)
        if lim is None:
            notes.append(f"{name}: not readable here, not checked")
            continue
        have = queued or 0
        if have + new_jobs > lim:
            raise SubmitError(f"the submission adds {new_jobs} job(s) (array tasks count one each) to the "
                              f"{have} already queued, beyond the site's {name} = {lim}: use fewer --shards "
                              "or wait for queued jobs to finish; nothing was submitted")
        notes.append(f"{name} = {lim}: {have} queued + {new_jobs} new")
    return notes


def _gapsweep_cmd(env: dict[str, str]) -> str:
    if env.get("GAPSWEEP"):
        return env["GAPSWEEP"]
    return f"{shlex.quote(sys.executable)} -m gapsweep"


def _sbatch(cmd: list[str], env: dict[str, str]) -> str:
    p = subprocess.run(cmd, capture_output=True, text=True, env=env, timeout=120)
    if p.returncode != 0:
        raise SubmitError(f"sbatch failed (exit {p.returncode}): {p.stderr.strip() or p.stdout.strip()}")
    return p.stdout.strip().split(";")[0]


def _validate(shards: int | None, mpi: int | None, max_running: int | None, requeue_max: int, lead: int) -> None:
    if (shards is None) == (mpi is None):
        raise ValueError("submit: give exactly one of --shards N and --mpi P")
    for name, v in (("--shards", shards), ("--mpi", mpi), ("--max-running", max_running)):
        if v is not None and (not isinstance(v, int) or v < 1):
            raise ValueError(f"{name}: expected an integer >= 1, got {v!r}")
    if not isinstance(requeue_max, int) or not 0 <= requeue_max <= 100:
        raise ValueError(f"--requeue: expected an integer 0 .. 100, got {requeue_max!r}")
    if not isinstance(lead, int) or not 10 <= lead <= 86400:
        raise ValueError(f"--signal-lead: expected seconds 10 .. 86400, got {lead!r}")


def submit(job: str | Path, out_dir: str | Path, *, shards: int | None = None, mpi: int | None = None,
           site: SiteOptions | None = None, max_running: int | None = None, requeue_max: int = 3,
           signal_lead: int = DEFAULT_LEAD, force: bool = False, dry_run: bool = False,
           run_args: list[str] | None = None) -> Submission:
    """Submit ``job`` to Slurm: ``shards`` array tasks and a merge job, or one ``mpi`` job of that many ranks;
    the final store is ``out_dir/<job file stem>.h5``. Raises ``ValueError`` for bad arguments, ``SpecError`` for
    a bad spec, :class:`SubmitError` when a site limit or jobs already queued for the store refuse it (nothing
    is submitted then). ``run_args``: more ``gapsweep run`` options for the run jobs."""
    from gapsweep.sweep import runner

    _validate(shards, mpi, max_running, requeue_max, signal_lead)
    site = site or SiteOptions.from_env()
    runner.plan(job)  # validates the spec before anything is queued
    job = Path(job).absolute()
    out = Path(out_dir).absolute()
    name = job.name[:-5] if job.name.endswith(".toml") else job.stem
    final = out / f"{name}.h5"
    sub = Submission(final, store_key(final))
    ident = store_identity(final)
    here = scripts_dir()
    _refuse_queued(sub, ident, force, dry_run)
    limits = site_limits()
    max_array = limits["MaxArraySize"] or DEFAULT_MAX_ARRAY
    chunks = split_array(shards, max_array) if shards else []
    sub.notes.extend(_check_limits(limits, (shards + 1) if shards else 1))
    if shards and len(chunks) > 1:
        sub.notes.append(f"{shards} shards in {len(chunks)} arrays (MaxArraySize = {max_array})")
    env = dict(os.environ)
    sub.env = {"GAPSWEEP": _gapsweep_cmd(env), "GAPSWEEP_REQUEUE": str(requeue_max),
               "GAPSWEEP_SIGNAL_LEAD": str(signal_lead)}
    if site.setup:
        sub.env["GAPSWEEP_SETUP"] = site.setup
    if mpi:
        sub.notes.extend(_mpi_launcher(env, sub.env, site))
    tag = comment(sub.key, ident)
    common = ["--parsable", *site.args(), "--requeue", f"--signal=B:USR1@{signal_lead}", f"--comment={tag}",
              "--open-mode=append"]
    extra = list(run_args or [])
    logs = sbatch_escape(out / name)  # the folder and name literal, then sbatch's patterns
    if mpi:
        sub.commands.append(["sbatch", *common, f"--ntasks={mpi}", f"--output={logs}.mpi-%j.out",
                             str(here / "mpi_job.sbatch"), str(job), str(final), *extra])
        sub.scripts["mpi_job.sbatch"] = (here / "mpi_job.sbatch").read_text()
    else:
        pattern = f"{out / name}.shard{{i}}.h5"
        for off, cnt in chunks:
            throttle = f"%{max_running}" if max_running else ""
            log_name = f"{logs}.shard%a-%A.out" if off == 0 else f"{logs}.shard{off}+%a-%A.out"
            sub.commands.append(["env", f"GAPSWEEP_SHARDS={shards}", f"GAPSWEEP_SHARD_OFFSET={off}", "sbatch",
                                 *common, f"--array=0-{cnt - 1}{throttle}", f"--output={log_name}",
                                 str(here / "array_job.sbatch"), str(job), pattern, *extra])
        sub.scripts["array_job.sbatch"] = (here / "array_job.sbatch").read_text()
        sub.scripts["merge_job.sbatch"] = (here / "merge_job.sbatch").read_text()
    if dry_run:
        if not mpi:
            sub.commands.append(_merge_cmd(site, tag, ["ARRAY_ID"] * len(chunks), out, name, pattern, shards,
                                           here))
        return sub
    out.mkdir(parents=True, exist_ok=True)
    jenv = {**env, **sub.env}
    ids: list[str] = []
    try:
        for c, e in _with_env(sub.commands, jenv):
            ids.append(_sbatch(c, e))  # one by one: those queued before a failure are named
        if mpi:
            sub.mpi = ids[0]
            return sub
        sub.arrays = ids
        mc = _merge_cmd(site, tag, ids, out, name, pattern, shards, here)
        sub.commands.append(mc)
        sub.merge = _sbatch(mc, jenv)
    except SubmitError as e:
        if ids:  # part of the submission is queued: say which, so that it can be cancelled or completed
            raise SubmitError(f"{e}; already submitted: {' '.join(ids)} (scancel {' '.join(ids)} to withdraw "
                              "them)") from None
        raise
    return sub


def _with_env(commands: list[list[str]], jenv: dict[str, str]) -> Iterator[tuple[list[str], dict[str, str]]]:
    """Each sbatch command with its environment: an array's command starts ``env GAPSWEEP_SHARDS=..
    GAPSWEEP_SHARD_OFFSET=..`` (its shard count and offset), which go into its environment instead."""
    for c in commands:
        if c[0] == "env":
            yield c[3:], {**jenv, **dict(x.split("=", 1) for x in c[1:3])}
        else:
            yield c, jenv


def _refuse_queued(sub: Submission, ident: str | None, force: bool, dry_run: bool) -> None:
    """Refuse (SubmitError) a second submission of one store: jobs with its comment queued or running already,
    or a queue that cannot be asked -- unless ``force`` (or ``dry_run``, for the latter: then a note says so)."""
    final = sub.store
    try:
        present = existing_jobs(sub.key, ident)
    except QueueUnknown as e:
        if not (force or dry_run):
            raise SubmitError(f"{e}: cannot tell whether jobs of store {final} are queued or running already, "
                              "so nothing was submitted (a second submission of one store is refused); run it "
                              "where squeue works, or pass --force to submit anyway") from None
        present = []
        sub.notes.append(f"{e}: jobs of this store already queued not checked")
    if present and not force:
        raise SubmitError(f"store {final} has jobs queued or running already: {', '.join(present)} (their "
                          "comment gapsweep:" + sub.key + "); wait for them, cancel them (scancel), or pass "
                          "--force to submit anyway")


def _merge_cmd(site: SiteOptions, tag: str, arrays: list[str], out: Path, name: str, pattern: str, shards: int,
               here: Path) -> list[str]:
    return ["sbatch", "--parsable", *site.args(merge=True), f"--comment={tag}",
            f"--dependency=afterany:{':'.join(arrays)}", "--kill-on-invalid-dep=yes", "--open-mode=append",
            f"--output={sbatch_escape(out / name)}.merge-%j.out", str(here / "merge_job.sbatch"), pattern,
            str(shards), str(out / f"{name}.h5")]


_VENDORS = (("Open MPI", ("open mpi", "openrte", "open-mpi")), ("Intel MPI", ("intel",)),
            ("MPICH", ("mpich", "hydra")))


def _vendor(text: str) -> str | None:
    """The MPI implementation a version text names (``mpiexec --version``, ``MPI.Get_library_version()``)."""
    low = text.lower()
    for name, needles in _VENDORS:
        if any(n in low for n in needles):
            return name
    return None


def _mpi4py_library() -> str | None:
    """mpi4py's MPI library version text, read in a child (MPI not initialised); None without mpi4py."""
    code = ("import mpi4py; mpi4py.rc.initialize = False; mpi4py.rc.finalize = False\n"
            "from mpi4py import MPI; print(MPI.Get_library_version())")
    try:
        p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return None
    if p.returncode != 0:
        return None
    return p.stdout.strip() or None


def _mpi_launcher(env: dict[str, str], jobs_env: dict[str, str], site: SiteOptions) -> list[str]:
    """The MPI launcher of an ``--mpi`` job (``GAPSWEEP_MPIEXEC`` into ``jobs_env``): the one beside the
    interpreter (a venv's own), else the one on ``PATH`` if it is of mpi4py's MPI; refused (SubmitError) when
    they differ, naming both. ``GAPSWEEP_LAUNCHER`` or a ``--setup`` hook (which may load another MPI) take
    the choice over. Returns notes."""
    if env.get("GAPSWEEP_LAUNCHER"):
        return [f"MPI launcher: GAPSWEEP_LAUNCHER = {env['GAPSWEEP_LAUNCHER']}"]
    beside = Path(sys.executable).parent / "mpiexec"  # not resolved: a venv's bin/, where its MPI puts mpiexec
    if beside.is_file() and os.access(beside, os.X_OK):
        jobs_env["GAPSWEEP_MPIEXEC"] = str(beside)
        return [f"MPI launcher: {beside} (beside {sys.executable})"]
    on_path = shutil.which("mpiexec", path=env.get("PATH"))
    if site.setup:
        return [f"MPI launcher: mpiexec of the jobs' PATH after the setup hook (here: {on_path or 'none'})"]
    lib = _mpi4py_library()
    if lib is None:
        return [f"MPI launcher: {on_path or 'mpiexec (none on PATH here)'}; mpi4py not importable here, its MPI "
                "not compared"]
    need = _vendor(lib) or lib.splitlines()[0][:60]
    if on_path is None:
        raise SubmitError(f"--mpi: no mpiexec beside {sys.executable} nor on PATH; mpi4py of this interpreter "
                          f"needs the mpiexec of {need}: put its bin/ on PATH, load it with --setup, or set "
                          "GAPSWEEP_LAUNCHER; nothing was submitted")
    p = _cmd([on_path, "--version"])
    have = _vendor((p.stdout + p.stderr) if p is not None else "")
    if have is not None and _vendor(lib) is not None and have != _vendor(lib):
        raise SubmitError(f"--mpi: the mpiexec on PATH ({on_path}) is {have}'s, but mpi4py of {sys.executable} "
                          f"was built with {need}: the ranks would not start together. Put that MPI's bin/ "
                          "on PATH (or activate the venv), load it with --setup, or set GAPSWEEP_LAUNCHER "
                          "(e.g. \"srun --mpi=pmix\"); nothing was submitted")
    jobs_env["GAPSWEEP_MPIEXEC"] = on_path
    return [f"MPI launcher: {on_path} ({have or 'implementation unknown'}; mpi4py: {need})"]


# ---------------------------------------------------------------------------------------------------------
# requeue (called by the job scripts after Slurm's warning signal stopped the run)


def _progress_file(store: Path) -> Path:
    return store.with_name(store.name + REQUEUE_SUFFIX)


def attempt_progress(store: str | Path) -> tuple[int, int, int]:
    """(rows finished now, rows finished when the store's last run started, rows of the store): the last run's
    ``todo`` says how many rows it had to run."""
    from gapsweep.sweep import storecheck
    from gapsweep.sweep.store import open_read

    with open_read(store, check=False) as f:
        n = f["results"].shape[0]
        done = int((f["results"].fields("status")[...] != 0).sum()) if n else 0
        runs = storecheck.run_records(f.attrs.get("runs", "[]"))
    todo = int(runs[-1].get("todo", n)) if runs else n
    return done, n - todo, n


def requeue(store: str | Path, max_requeues: int, job_id: str | None = None, *, act: bool = True,
            ) -> tuple[bool, str]:
    """Decide whether the job (``job_id``, default ``$SLURM_JOB_ID``) whose run on ``store`` was stopped by the
    time-limit warning requeues itself, and do it (``scontrol requeue``) when ``act``. Not when it was requeued
    ``max_requeues`` times already (the count is kept in ``STORE.requeue`` for this job id; a new submission
    starts again at 0), nor when its last attempt finished no row (it would only time out again), nor when every
    row is finished. Returns (requeued, why)."""
    path = Path(store)
    job_id = job_id or os.environ.get("SLURM_JOB_ID", "")
    if not job_id:
        return False, "not inside a Slurm job (SLURM_JOB_ID unset)"
    if not path.is_file():
        return False, f"store {path} does not exist"
    pf = _progress_file(path)
    try:
        rec = json.loads(pf.read_text()) if pf.is_file() else {}
    except (OSError, ValueError):
        rec = {}
    if rec.get("job") != job_id:
        rec = {"job": job_id, "requeues": 0, "history": []}
    done, at_start, n = attempt_progress(path)
    if done >= n:
        return False, f"all {n} rows finished"
    before = max(at_start, rec["history"][-1]["finished"] if rec["history"] else -1)
    if done <= before:
        return False, (f"no row finished since its last start or requeue ({done} of {n} finished): "
                       "requeueing would only reach the time limit again; give the jobs more --time")
    if rec["requeues"] >= max_requeues:
        return False, f"requeued {rec['requeues']} time(s) already (--requeue {max_requeues})"
    rec["requeues"] += 1
    rec["history"].append({"finished": done, "of": n})
    tmp = pf.with_name(pf.name + f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(rec))
    os.replace(tmp, pf)
    why = (f"requeue {rec['requeues']} of {max_requeues}: {done} of {n} rows finished ({done - at_start} in "
           "this attempt)")
    if act:
        p = _cmd(["scontrol", "requeue", job_id])
        if p is None or p.returncode != 0:
            return False, f"scontrol requeue {job_id} failed: {p.stderr.strip() if p else 'scontrol not found'}"
    return True, why

