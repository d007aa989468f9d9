"""Provenance recorded in every store: package and library versions, git commit, times (docs/store.md)."""

from __future__ import annotations

import datetime as _dt
import json
import logging
import os
import re
import subprocess
from functools import lru_cache
from importlib import metadata
from pathlib import Path
from typing import Any

__all__ = ["git_commit", "now", "rebuilt", "run_extras", "sde_engine", "spec_attrs", "store_attrs", "versions"]

log = logging.getLogger(__name__)

_PACKAGES = ("gapsweep", "numpy", "scipy", "h5py", "mpi4py", "pyfftw", "warp-lang", "numba", "pandas")


def now() -> str:
    """UTC time, ISO 8601 with seconds."""
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


@lru_cache(maxsize=1)
def versions() -> dict[str, str]:
    """Installed versions (from package metadata: nothing heavy such as warp is imported) and HDF5's."""
    out: dict[str, str] = {}
    for p in _PACKAGES:
        try:
            out[p] = metadata.version(p)
        except metadata.PackageNotFoundError:
            out[p] = "not installed"
    if out["gapsweep"] == "not installed":  # imported from a source tree (PYTHONPATH), not pip-installed
        from gapsweep import __version__

        out["gapsweep"] = f"{__version__} (source tree)"
    out["cupy"] = _cupy_version()
    try:
        import h5py

        out["hdf5"] = h5py.version.hdf5_version
        out["h5py_mpi"] = str(bool(h5py.get_config().mpi))
    except Exception:  # pragma: no cover
        out["hdf5"] = "unknown"
    return out


@lru_cache(maxsize=1)
def git_commit() -> str:
    """Commit of the source tree gapsweep was imported from (``-dirty`` if modified), ``$GAPSWEEP_GIT_COMMIT``
    where that is set (a copy of the tree without ``.git``, e.g. on a compute node), or ``unknown``."""
    if os.environ.get("GAPSWEEP_GIT_COMMIT"):
        return os.environ["GAPSWEEP_GIT_COMMIT"]
    root = Path(__file__).resolve().parents[2]
    try:
        p = subprocess.run(["git", "-C", str(root), "rev-parse", "--verify", "HEAD"], capture_output=True,
                           text=True, timeout=10)
        sha = p.stdout.strip()
        if p.returncode != 0 or not re.fullmatch(r"[0-9a-f]{40}", sha):
            log.debug("no git commit for %s (not a checkout): recorded as 'unknown'", root)
            return "unknown"
        dirty = subprocess.run(["git", "-C", str(root), "status", "--porcelain", "--untracked-files=no"],
                               capture_output=True, text=True, timeout=10).stdout.strip()
        return sha + ("-dirty" if dirty else "")
    except (OSError, subprocess.SubprocessError) as e:
        log.debug("git not usable (%s): commit recorded as 'unknown'", e)
        return "unknown"


def store_attrs(spec: Any, *, shard: str = "", extra: dict[str, Any] | None = None) -> dict[str, Any]:
    """Static file attributes of a new store (the same on every rank)."""
    from gapsweep import __version__
    from gapsweep.sweep.schema import FORMAT, FORMAT_VERSION

    a: dict[str, Any] = {
        "format": FORMAT,
        "format_version": FORMAT_VERSION,
        "job_name": spec.name,
        "spec_text": spec.text,
        "spec_sha256": spec.sha256,
        "shard": shard,
        "gapsweep_version": __version__,
        "git_commit": git_commit(),
        "versions": json.dumps(versions(), sort_keys=True),
        "created": now(),
        "runs": "[]",
    }
    units = spec.units() if hasattr(spec, "units") else {}
    if any(units.values()):  # physical units of lengths and pressures (docs/store.md); absent: model units
        a["units"] = json.dumps(units, sort_keys=True)
    if getattr(spec, "surface", {}).get("kind") == "file" and getattr(spec, "base_dir", ""):
        a["spec_dir"] = spec.base_dir  # where the height map's path is relative to (merge re-reads the spec)
    if getattr(spec, "surface", {}).get("kind") == "file":
        # the map as solved: undefined pixels and what was done with them, crop, channel, rms (docs/store.md)
        from gapsweep.sweep.filesurface import surface_map_attr

        rec = surface_map_attr(spec.surface)
        if rec:
            a["surface_map"] = rec
    a.update(extra or {})
    return a


def spec_attrs(spec: Any) -> dict[str, Any]:
    """The attributes a store takes from its job spec (:func:`store_attrs`): ``job_name``, ``spec_text``,
    ``spec_sha256``, ``units`` (where the job has physical units) and ``spec_dir`` (a file surface's folder)."""
    a = store_attrs(spec)
    return {k: a[k] for k in ("job_name", "spec_text", "spec_sha256", "units", "spec_dir") if k in a}


def rebuilt(names: list[str] | tuple[str, ...]) -> dict[str, Any]:
    """Values for provenance attributes that failed their checksum (issue 40 item 1): what they held is lost;
    each says so, with the time of the repair, keeping its kind (JSON where it was JSON)."""
    note = f"unknown: the attribute was damaged (failed its checksum) and rebuilt at {now()}"
    out: dict[str, Any] = {}
    for k in names:
        if k == "versions":
            out[k] = json.dumps({"lost": note}, sort_keys=True)
        elif k == "merged_from":
            out[k] = json.dumps([note])
        else:
            out[k] = note
    return out


def _cupy_version() -> str:
    """Version of the installed cupy wheel (``cupy-cudaXXx`` or a source build), from package metadata."""
    for name in ("cupy", "cupy-cuda13x", "cupy-cuda12x", "cupy-cuda11x"):
        try:
            return f"{metadata.version(name)} ({name})"
        except metadata.PackageNotFoundError:
            continue
    return "not installed"


def sde_engine(scheme: str = "split") -> str:
    """The engine of SDE ensembles on a CUDA device in this process (gapsweep.sweep.methods.sde.sde_engine)."""
    from gapsweep.sweep.methods.sde import sde_engine as engine

    return engine(scheme)


def run_extras(spec: Any, *, gpu_ranks: list, batch: str, batch_units: int) -> dict[str, Any]:
    """Run-record entries about the hardware path: the GPU of each rank (None: CPU only), the GFMD batch mode
    and count of batch units, and for a job with SDE on CUDA the SDE engine (``sde_engine``)."""
    from gapsweep.sweep import methods as registry

    out: dict[str, Any] = {"gpus": list(gpu_ranks), "gfmd_batch": batch, "batch_units": int(batch_units)}
    for name, options in spec.methods.items():
        out.update(registry.get(name).provenance(options))
    return out
