"""Standard data views of a store: an ``xarray.Dataset``, a netCDF4 export, a tolerant diff, kept fields.

* :func:`to_dataset` opens a store by path as an ``xarray.Dataset`` with dims ``hurst``, ``rho``, ``sigma0`` and
  ``seed``. Seed-dependent results (GFMD, the discrete theory, SDE ensembles over several seeds) carry the
  ``seed`` dimension; seed-independent ones (the paper's and the continuum theory, a Fokker-Planck density)
  have no ``seed`` dimension, so that ``ds.gfmd_mean_gap - ds.theory_paper`` broadcasts over every seed.
  Every variable has CF-style ``units`` (UDUNITS strings: model quantities are dimensionless, ``"1"``, with the
  model unit they are measured in under ``reference_unit``, docs/model.md M1) and a ``long_name``; the status
  variables are CF flags (``flag_values``, ``flag_meanings``); the file attributes carry the provenance
  (job, spec hash, versions, git commit).
* :func:`export_netcdf` writes that dataset as a netCDF4 file (xarray, ``ncdump``, netCDF4-python open it).
* :func:`diff` compares two stores with a tolerance (``rtol``, ``atol``) on the float results and histograms.
* Kept fields: a job spec may ask GFMD to keep the full fields of chosen tasks (``[methods.gfmd] keep_fields``,
  docs/jobs.md). Each is written, atomically, to ``<store>.fields/<task_id>.nc``: a netCDF4 file with the
  variables ``gap``, ``pressure``, ``displacement``, ``height`` on ``(x, y)``, chunked and compressed;
  :func:`open_fields` reads them back with xarray.

xarray and h5netcdf are the ``xarray`` extra (``pip install 'gapsweep[xarray]'``); writing kept fields needs
only h5py.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from gapsweep.core.extras import require
from gapsweep.sweep import methods as registry
from gapsweep.sweep import writefail
from gapsweep.sweep.fields import FIELD_META, FIELD_NAMES, field_selected, fields_dir, write_fields  # noqa: F401 - names of 0.1
from gapsweep.sweep.schema import FLOAT_RESULTS, STATUS, StoreWriteError

__all__ = [
    "FIELD_NAMES",
    "diff",
    "export_netcdf",
    "field_selected",
    "fields_dir",
    "from_frame",
    "open_fields",
    "to_dataset",
    "write_fields",
]

DIMS = ("hurst", "rho", "sigma0", "seed")
COORD_META = {
    "hurst": {"long_name": "Hurst exponent H of the surface spectrum (0: a surface from a file)", "units": "1"},
    "rho": {"long_name": "range rho of the interaction (exponential repulsion, adhesion; 0: hard wall)",
            "units": "1", "reference_unit": "L"},
    "sigma0": {"long_name": "applied mean pressure sigma0", "units": "1", "reference_unit": "E*"},
    "seed": {"long_name": "seed of the random surface (and of the SDE noise)", "units": "1"},
}
_LEN = {"units": "1", "reference_unit": "L"}


def _variables() -> dict[str, tuple[dict[str, tuple[str, str, dict[str, str]]], tuple[str, ...], str | None]]:
    """Per method: store column -> (variable, long_name, unit attributes), the seed-free columns and the option
    of which one value is kept (the method plug-ins declare them, gapsweep.sweep.methods)."""
    out = {}
    for name, m in registry.all_methods().items():
        cols = dict(m.variables)
        # plug-in columns (docs/store.md "Plug-in columns"): the method's own and its extensions', named
        # <method>_<column> unless the plug-in names the variable itself
        own = {**m.own_columns, **{k: c for e in registry.extensions(name).values() for k, c in e.own_columns.items()}}
        for e in registry.extensions(name).values():
            cols.update(e.variables)
        for k, c in own.items():
            cols.setdefault(k, (f"{name}_{k}", c.description, c.units))
        out[name] = (cols, m.seed_free, m.select)
    return out


def _int_columns() -> set[str]:
    """Integer columns whose -1 means "not computed" (NaN in the view): built-in ones and plug-ins' "int" ones."""
    out = {"iterations", "flags"}
    for name, m in registry.all_methods().items():
        for cols in (m.own_columns, *(e.own_columns for e in registry.extensions(name).values())):
            out.update(k for k, c in cols.items() if c.kind == "int")
    return out


STATUS_FLAGS = dict(STATUS)



# ---------------------------------------------------------------------------------------------------------
# xarray views


def _xr():
    return require("xarray", "gapsweep.store.to_dataset (an xarray view of a store)")


def _pick(sub: Any, col: str, want: float | None, label: str, method: str, attrs: dict[str, Any]) -> Any:
    """Rows of one GFMD grid ``n`` / one SDE or FP ``c2`` (default: the finest grid, the smallest C2)."""
    vals = sorted(set(sub[col].dropna()))
    if len(vals) <= 1:
        return sub
    pick = want if want is not None else (max(vals) if col == "n" else min(vals))
    keep = np.isclose(sub[col].to_numpy(float), float(pick), rtol=1e-9, atol=0.0)
    if not keep.any():
        raise ValueError(f"{label}: {method} has {col} values {vals}, got {want!r}")
    attrs[f"{method}_{col}"] = pick if col != "n" else int(pick)
    return sub[keep]


def from_frame(df: Any, *, n: int | None = None, c2: float | None = None, attrs: Mapping[str, Any] | None = None):
    """The dataset of :func:`to_dataset` from a store frame (:func:`gapsweep.store.read`)."""
    import pandas as pd

    xr = _xr()
    need = ("method", "status", "hurst", "rho", "sigma0", "seed")
    missing = [c for c in need if c not in df.columns]
    if missing:
        raise ValueError(f"df lacks the contract column(s) {missing}; see gapsweep.store.read")
    coords = {k: np.sort(df[k].unique()) for k in DIMS}
    shape = tuple(len(v) for v in coords.values())
    index = {k: {v: i for i, v in enumerate(c)} for k, c in coords.items()}
    ds_attrs: dict[str, Any] = {}
    data: dict[str, Any] = {}
    ints = _int_columns()
    for method, (cols, seed_free, select) in _variables().items():
        sub = df[df["method"].astype(str) == method]
        if sub.empty:
            continue
        if select is not None and select in sub:
            sub = _pick(sub, select, {"n": n, "c2": c2}.get(select), select, method, ds_attrs)
        idx = tuple(np.array([index[k][v] for v in sub[k]], dtype=int) for k in DIMS)
        done = (sub["status"].astype(str) == "done").to_numpy()
        for col, (name, long_name, units) in cols.items():
            if col not in sub:
                continue
            vals = pd.to_numeric(sub[col], errors="coerce").to_numpy(float)
            if col in ints:
                vals = np.where(vals < 0, np.nan, vals)
            if not np.isfinite(vals[done]).any():
                continue
            a = np.full(shape, np.nan)
            a[tuple(i[done] for i in idx)] = vals[done]
            meta = {"long_name": long_name, **units}
            # seed-free only where the values agree between seeds (h_rms = "surface" with gaussian amplitudes
            # makes the paper's form seed-dependent: then the seed dimension stays)
            if col in seed_free and _seed_independent(a):
                data[name] = (DIMS[:3], _collapse_seed(a, name), {**meta, "comment": "seed-independent: "
                              "no seed dimension, broadcasts over every seed"})
            else:
                data[name] = (DIMS, a, meta)
        st = np.full(shape, -1, dtype=np.int8)
        st[idx] = [STATUS_FLAGS.get(x, -1) for x in sub["status"].astype(str)]
        data[f"{method}_status"] = (DIMS, st, {
            "long_name": f"status of the {method} task", "units": "1", "_FillValue": np.int8(-1),
            "flag_values": np.array(list(STATUS_FLAGS.values()), dtype=np.int8),
            "flag_meanings": " ".join(STATUS_FLAGS)})
    ds = xr.Dataset({k: xr.Variable(d, a, attrs={k2: v2 for k2, v2 in m.items() if k2 != "_FillValue"})
                     for k, (d, a, m) in data.items()}, coords=coords)
    for k, (_, _, m) in data.items():
        if "_FillValue" in m:
            ds[k].encoding["_FillValue"] = m["_FillValue"]
    for k, m in COORD_META.items():
        ds[k].attrs.update(m)
    ds.attrs.update({"Conventions": "CF-1.10", "title": "gapsweep store", **ds_attrs, **dict(attrs or {})})
    return ds


def _seed_independent(a: np.ndarray) -> bool:
    """Whether the finite values of ``a`` (dims hurst, rho, sigma0, seed) agree between seeds (rtol 1e-12)."""
    with np.errstate(invalid="ignore"):
        lo = np.nanmin(np.where(np.isnan(a), np.inf, a), axis=3)
        hi = np.nanmax(np.where(np.isnan(a), -np.inf, a), axis=3)
    have = np.isfinite(lo)
    return not np.any(have & ~np.isclose(lo, hi, rtol=1e-12, atol=0.0))


def _collapse_seed(a: np.ndarray, name: str) -> np.ndarray:
    """Drop the seed axis of a seed-independent result; different values at different seeds are an error."""
    with np.errstate(invalid="ignore"):
        lo, hi = np.nanmin(np.where(np.isnan(a), np.inf, a), axis=3), np.nanmax(np.where(np.isnan(a), -np.inf, a),
                                                                               axis=3)
    have = np.isfinite(lo)
    if np.any(have & ~np.isclose(lo, hi, rtol=1e-12, atol=0.0)):
        raise ValueError(f"{name}: values differ between seeds although the result is seed-independent")
    return np.where(have, lo, np.nan)


def _provenance(path: str | Path, damaged: Sequence[str] = ()) -> dict[str, Any]:
    """The store's attributes for the dataset; ``damaged`` (attributes that fail their checksum) are left out
    and named in ``gapsweep_damaged_attributes``."""
    from gapsweep import __version__
    from gapsweep.sweep import store

    a = store.read_attrs(path)
    keep = ("format", "format_version", "job_name", "spec_sha256", "shard", "gapsweep_version", "git_commit",
            "versions", "created", "finished", "runs", "merged_from", "spec_text")
    out = {f"gapsweep_{k}" if not k.startswith("gapsweep") else k: (v if isinstance(v, str) else
                                                                     (v.item() if hasattr(v, "item") else v))
           for k, v in a.items() if k in keep and k not in damaged}
    if damaged:
        out["gapsweep_damaged_attributes"] = json.dumps(sorted(damaged))
    out.update({"title": f"gapsweep store of job {a.get('job_name', '?')}",
                "source": f"gapsweep {a.get('gapsweep_version', '?')} (read by gapsweep {__version__})",
                "history": f"opened from {Path(path).resolve()} by gapsweep.store.to_dataset",
                "references": "docs/model.md (the model), docs/store.md (the store)"})
    return out


def to_dataset(path: str | Path, *, n: int | None = None, c2: float | None = None, skip_damaged: bool = False):
    """Open the store at ``path`` as an ``xarray.Dataset`` (module docstring). ``n`` picks the GFMD (and discrete
    theory) grid and ``c2`` the SDE / Fokker-Planck fudge factor when a store holds several (default: the
    finest grid, the smallest C2); the choices are recorded in the attributes. A store with damaged rows
    (checksum mismatch, docs/store.md) is refused unless ``skip_damaged`` (then those rows are left out and
    counted in the attribute ``gapsweep_damaged_rows``)."""
    from gapsweep.sweep import store

    _xr()
    df = store.read(path)
    damaged = int((df["status"] == "damaged").sum())
    if damaged and not skip_damaged:
        raise store.StoreError(f"store {path}: {damaged} damaged row(s) (checksum mismatch; `gapsweep status` "
                               "names them): re-run them with --resume, or pass --skip-damaged to leave them out")
    spec_text, units, bad = _trusted_spec(path)
    attrs = _provenance(path, bad)
    if damaged:
        attrs["gapsweep_damaged_rows"] = damaged
    ds = from_frame(df, n=n, c2=c2, attrs=attrs)
    ds = _drop_placeholders(ds, spec_text)
    return apply_units(ds, units)


def _trusted_spec(path: str | Path) -> tuple[str | None, dict[str, Any], list[str]]:
    """The store's spec text (None where it is damaged), its units and the attributes that fail their checksum
    (issue 40 item 1: every row verifies on its own, so damaged attributes are worked around, not refused).
    Units come from the attribute, or from the spec where the attribute is damaged; where both are, the export
    is refused (no unit would be honest)."""
    from gapsweep.sweep import repair, store, storecheck

    with store.open_read(path, check=False) as f:
        rep = storecheck.check(f, path)
        meta = {k: (v.decode("utf-8", "replace") if isinstance(v, bytes) else v) for k, v in f.attrs.items()}
        own = None if rep.spec_trusted else repair.own_spec(f)
    bad = [*rep.provenance_damaged, *rep.spec_damaged, *(["runs"] if rep.runs_damaged else [])]
    if rep.spec_trusted:
        return meta.get("spec_text", ""), json.loads(meta.get("units", "{}") or "{}"), bad
    if own is not None:  # the spec text matches its hash and the task table: its units are the store's
        units = own.units() if hasattr(own, "units") else {}
        return own.text, (units if any(units.values()) else {}), [x for x in bad if x not in ("spec_text",
                                                                                            "spec_sha256")]
    if "units" in rep.spec_damaged or rep.integrity_damaged:
        raise store.StoreError(f"store {path}: its attributes 'units' and 'spec_text' are both damaged (or "
                               "unverifiable): the physical units are unknown; `gapsweep repair STORE --job JOB` "
                               "restores them (the rows verify on their own checksums)")
    return None, json.loads(meta.get("units", "{}") or "{}"), bad


def _drop_placeholders(ds: Any, spec_text: str | None) -> Any:
    """Leave out the axes a job does not have: ``hurst`` for a measured map (it is 0 there), ``rho`` for the
    hard wall (0: no interaction range)."""
    import tomllib

    if spec_text is None:  # a damaged spec text: the data tell (H = 0 only for a map, rho = 0 only for the wall)
        def zero(d: str) -> bool:
            return d in ds.coords and ds.sizes.get(d) == 1 and float(ds[d][0]) == 0.0

        raw = {"surface": {"kind": "file" if zero("hurst") else ""},
               "interaction": {"kind": "hard_wall" if zero("rho") else ""}}
    else:
        try:
            raw = tomllib.loads(spec_text)
        except (tomllib.TOMLDecodeError, TypeError):
            return ds
    drop = []
    if raw.get("surface", {}).get("kind") == "file":  # one map: no Hurst exponent, one "seed"
        drop += ["hurst", "seed"]
    if raw.get("interaction", {}).get("kind") == "hard_wall":
        drop.append("rho")
    for d in drop:
        if d in ds.dims and ds.sizes[d] == 1 and float(ds[d][0]) == 0.0 and d in ds.coords:
            ds = ds.isel({d: 0}, drop=True)
    return ds


def apply_units(ds: Any, units: Mapping[str, str | None]) -> Any:
    """Give every variable and coordinate measured in the model's length ``L`` or pressure ``E*`` the job's
    physical unit (CF ``units``, e.g. ``"um"``, ``"MPa"``, ``"MPa um"`` for an energy per area) when the store
    records one (attribute ``units``, docs/store.md), spelled for UDUNITS (``"A"`` is written ``"angstrom"``,
    not ampere); model units stay ``"1"`` with ``reference_unit``. ``gapsweep_units`` keeps the job's own
    spelling."""
    from gapsweep.sweep.fields import cf_unit

    length, pressure = cf_unit(units.get("length")), cf_unit(units.get("pressure"))
    phys = {"L": length, "E*": pressure, "E* L": f"{pressure} {length}" if pressure and length else None}
    for name in [*ds.data_vars, *ds.coords]:
        a = ds[name].attrs
        u = phys.get(a.get("reference_unit", ""))
        if u:
            a["units"] = u
            del a["reference_unit"]
    if length or pressure:
        ds.attrs["gapsweep_units"] = json.dumps(dict(units), sort_keys=True)
    return ds


def export_netcdf(path: str | Path, out: str | Path, *, overwrite: bool = False, **kw: Any) -> Path:
    """Write :func:`to_dataset` of the store ``path`` to the netCDF4 file ``out`` (written to a temporary name
    and moved into place: never half-written). Refuses to replace ``out`` unless ``overwrite``."""
    from gapsweep.sweep import outputs

    outp = Path(out)
    outputs.guard_file_output(outp, [path], "export --out")  # never the store itself nor another store (issue 19)
    # issue 31: --overwrite replaces only an earlier export, never another file
    outputs.guard_output(outp, [path], "export --out", overwrite=overwrite,
                         own=lambda o: None if outputs.is_export(o) else "is not a netCDF file written by "
                         "gapsweep export")
    ds = to_dataset(path, **kw)
    require("h5netcdf", "the netCDF4 export")
    outp.parent.mkdir(parents=True, exist_ok=True)
    from gapsweep.sweep import lease

    # issue 40 item 2: two exports to one --out shared one temporary name and took no lease, so the one that
    # exited 0 could leave the other store's data in the file. Now the output's lease excludes a second export
    # (refused, naming the holder) and the temporary name is this process's own.
    with lease.acquire(outp, purpose="export"):
        lease.remove_leftovers(outp, held=True)  # of a killed export (issue 40 item 7)
        outputs.guard_output(outp, [path], "export --out", overwrite=overwrite,  # again: one may have finished
                             own=lambda o: None if outputs.is_export(o) else "is not a netCDF file written by "
                             "gapsweep export")
        tmp = outp.with_name(f".{outp.name}.tmp-{os.getpid()}-{os.urandom(4).hex()}")
        # room first (the data, 1.5x for HDF5's and netCDF's own structures, + 1 MiB): a write that fails inside
        # h5netcdf crashed HDF5 2.0 (gapsweep.sweep.writefail.reserve)
        err = writefail.reserve(tmp, int(1.5 * ds.nbytes) + (1 << 20))
        if err is not None:
            raise StoreWriteError(f"export --out {outp}: cannot be written ({err}); nothing was written, the "
                                  "store is untouched")
        try:
            _write_nc(ds, tmp, outp)
            os.replace(tmp, outp)
        finally:
            if tmp.exists():
                tmp.unlink()
    return outp


def _write_nc(ds: Any, tmp: Path, outp: Path) -> None:
    """``ds.to_netcdf(tmp)``; a write error (full disk, file-size limit) becomes one line naming ``outp``. HDF5
    crashes when the objects of a file whose write failed are released (issue 31: export segfaulted after its
    message), so they are kept to the end of the process (store.write_failed) and the CLI leaves with os._exit."""
    from gapsweep.sweep import store

    try:
        with store._quiet_dealloc():
            ds.to_netcdf(tmp, engine="h5netcdf", format="NETCDF4")
    except (OSError, RuntimeError) as e:
        raise store.write_failed(f"export --out {outp}: writing failed ({e}); nothing was written, the store "
                                 "is untouched") from None


# ---------------------------------------------------------------------------------------------------------
# tolerant diff


def diff(a: str | Path, b: str | Path, *, rtol: float = 0.0, atol: float = 0.0,
         ignore: Sequence[str] = ("wall_time", "rank")) -> list[str]:
    """Differences in content between two stores (empty list: equal within the tolerance).

    Parameters and statuses must match exactly; float results and histograms within
    ``|x - y| <= atol + rtol |y|`` (NaN equals NaN), integer results exactly. ``ignore`` lists result columns
    left out (wall time and rank by default). With ``rtol = atol = 0`` this is a bit-for-bit comparison."""
    from gapsweep.sweep import store

    if not (rtol >= 0 and atol >= 0 and math.isfinite(rtol) and math.isfinite(atol)):
        raise ValueError(f"rtol and atol must be finite and >= 0, got rtol={rtol!r}, atol={atol!r}")
    out: list[str] = []
    ma, mb = store.read_attrs(a), store.read_attrs(b)
    if ma.get("spec_sha256") != mb.get("spec_sha256"):
        out.append("spec_sha256 differs")
    da, db = store.read(a, mark_damaged=False), store.read(b, mark_damaged=False)
    if len(da) != len(db):
        return [*out, f"task count {len(da)} != {len(db)}"]
    if list(da["task_id"]) != list(db["task_id"]):
        db = db.set_index("task_id").reindex(da["task_id"]).reset_index()
        if db["method"].isna().any():
            return [*out, "task ids differ"]
    for col in da.columns:
        if col in ignore or col == "task_id":
            continue
        x, y = da[col].to_numpy(), db[col].to_numpy()
        if col in FLOAT_RESULTS:
            bad = ~_close(x.astype(float), y.astype(float), rtol, atol)
        elif x.dtype.kind == "f":
            bad = ~((x == y) | (np.isnan(x) & np.isnan(y)))
        else:
            bad = x != y
        if bad.any():
            rows = np.flatnonzero(bad)
            kind = "results" if col in FLOAT_RESULTS or col in ("status", "message", "iterations", "count") \
                else "tasks"
            worst = ""
            if col in FLOAT_RESULTS:
                dd = np.abs(x.astype(float) - y.astype(float))[rows]
                worst = f", max |diff| {np.nanmax(dd) if np.isfinite(dd).any() else float('nan'):.3g}"
            out.append(f"{kind}.{col} differs in {rows.size} rows (first: {rows[:5].tolist()}{worst})")
    ha, hb = store.read_histograms(a), store.read_histograms(b)
    if set(ha) != set(hb):
        out.append(f"histograms: {len(set(ha) ^ set(hb))} tasks have a histogram in one store only")
    nbad = sum(1 for t in set(ha) & set(hb)
               if ha[t][0].shape != hb[t][0].shape or not (_close(ha[t][0], hb[t][0], rtol, atol).all()
                                                          and _close(ha[t][1], hb[t][1], rtol, atol).all()))
    if nbad:
        out.append(f"histograms differ for {nbad} tasks")
    return out


def _close(x: np.ndarray, y: np.ndarray, rtol: float, atol: float) -> np.ndarray:
    x, y = np.asarray(x, float), np.asarray(y, float)
    with np.errstate(invalid="ignore"):
        return (np.isnan(x) & np.isnan(y)) | (x == y) | (np.abs(x - y) <= atol + rtol * np.abs(y))


# ---------------------------------------------------------------------------------------------------------
# kept fields


def _field_files(store_path: str | Path) -> dict[str, Path]:
    """Kept-field files of a store and, for a merged store, of the shards it was merged from."""
    from gapsweep.sweep import store

    dirs = [fields_dir(store_path)]
    try:
        merged = json.loads(store.read_attrs(store_path).get("merged_from", "[]") or "[]")
    except (ValueError, FileNotFoundError):
        merged = []
    dirs += [fields_dir(s) for s in merged]
    out: dict[str, Path] = {}
    for d in dirs:
        if d.is_dir():
            for f in sorted(d.glob("*.nc")):
                out.setdefault(f.stem, f)
    return out


def open_fields(store_path: str | Path, task_ids: Iterable[str] | None = None):
    """The kept fields of a store as ``xarray.Dataset`` s: ``{task_id: Dataset}`` (dims ``x``, ``y``; the task's
    parameters and status in the attributes). ``task_ids`` restricts the selection."""
    xr = _xr()
    require("h5netcdf", "reading kept fields")
    files = _field_files(store_path)
    want = set(task_ids) if task_ids is not None else None
    return {t: xr.load_dataset(p, engine="h5netcdf") for t, p in files.items() if want is None or t in want}
