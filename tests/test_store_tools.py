"""Issue 40 items 2, 3, 7, 8, 9: the store's tools around its rows.

* item 2: two exports to one ``--out``: the second, started while the first writes (a barrier inside the first,
  not a sleep), is refused by the output's lease; the file holds the data of the export that exited 0. Before,
  both shared one fixed temporary name and the one that exited 0 could leave the other store's data.
* item 3: ``merge`` under a file-size limit (RLIMIT_FSIZE in a subprocess) ends with one line and exit 1, nothing
  written and the shard untouched (it segfaulted: the whole output is now reserved before HDF5 writes); seeded
  byte flips in the HDF5 metadata (object headers, the global heap of the attribute strings, B-trees, local
  heaps) end every reading command with exit 0 or one line and exit 1 -- never a traceback or a crash (a
  KeyError from h5py was a traceback; a flip in the global heap segfaulted: reads are now tried in a forked
  child first).
* item 7: the hidden temporary file of a SIGKILLed creation, merge or export (``.NAME.tmp-*``) is removed by the
  next command on that store -- status (when no live lease holds the store: none, or its holder dead), a run,
  merge or export under their lease -- and named; a live holder's file is kept. Before it stayed for good.
* item 8: a reader of a store that a live process is writing (its lease) retries a read that fails, and where the
  failure persists says "being written by ..." instead of "truncated or damaged" (78 of 4,241 polling reads of a
  running mpio store were told so); without a live writer the damage is named as before.
* item 9: ``status --json`` reports a store whose task table fails its checksum (it refused it where ``status``
  reported and went on); a flat height map fails ``plan`` with one error naming ``surface.path`` (every task
  failed at run time); the merge job script with a shard count or pattern that matches nothing exits non-zero.
"""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import h5py
import numpy as np
import pytest

from gapsweep import spec
from tests.storekit import ROOT, UNITS_JOB, cli_run, copy_store, run_job, units_store

JOB = UNITS_JOB


@pytest.fixture(scope="module")
def ref(tmp_path_factory) -> Path:
    return units_store(tmp_path_factory, "tools")


# ---- item 9 --------------------------------------------------------------------------------------------------


def test_status_json_reports_a_damaged_task_table(ref, tmp_path, capsys):
    path = copy_store(ref, tmp_path)
    with h5py.File(path, "r+") as f:
        t = f["tasks"][...]
        tid = bytearray(t["task_id"][1])
        tid[3] ^= 1
        t["task_id"][1] = bytes(tid)
        f["tasks"][...] = t
    rc, out, err = cli_run(capsys, "status", "--json", path)
    assert rc == 0, err
    js = json.loads(out)
    assert any("table '/tasks'" in x for x in js["check"]), js["check"]
    assert sum(js["total"].values()) == 2 and js["total"].get("damaged") == 1, js["total"]
    rc, out, _ = cli_run(capsys, "status", path)
    assert rc == 0 and "table '/tasks'" in out


@pytest.mark.parametrize("detrend,heights", [
    ("mean", lambda x, y: np.full(x.shape, 3.0)),             # a constant map
    ("plane", lambda x, y: 0.3 * x - 0.7 * y + 2.0),           # a tilted plane, flat once detrended
])
def test_flat_map_fails_plan(tmp_path, capsys, detrend, heights):
    x, y = np.meshgrid(np.arange(24.0), np.arange(20.0), indexing="ij")
    np.save(tmp_path / "flat.npy", heights(x, y))
    job = tmp_path / "flat.toml"
    job.write_text('[job]\nname = "flat"\n[grid]\nsigma0 = [1e-2]\n[surface]\nkind = "file"\npath = "flat.npy"\n'
                   f'pixel_size = 1.0\ndetrend = "{detrend}"\n[interaction]\nkind = "hard_wall"\n[methods.gfmd]\n')
    rc, _, err = cli_run(capsys, "plan", job)
    assert rc == 2 and "surface.path" in err and "flat" in err and "Traceback" not in err, err
    assert len([x for x in err.splitlines() if "invalid job spec" in x]) == 1
    # a rough map of the same shape passes (the check is not a blanket refusal)
    np.save(tmp_path / "flat.npy", np.random.default_rng(3).normal(size=x.shape))
    assert spec.load(job).surface["kind"] == "file"


@pytest.mark.parametrize("args,needle", [
    (["s{i}.h5", "0", "m.h5"], "integer >= 1"),
    (["s{i}.h5", "two", "m.h5"], "integer >= 1"),
    (["s.h5", "2", "m.h5"], "has no {i}"),
    (["none{i}.h5", "2", "m.h5"], "matches no shard store"),
])
def test_merge_job_with_nothing_to_merge_fails(tmp_path, args, needle):
    """bash runs the merge job script as Slurm does; ``gapsweep`` is a stub that would succeed."""
    env = {**os.environ, "SLURM_SUBMIT_DIR": str(tmp_path), "GAPSWEEP": "true"}
    p = subprocess.run(["bash", str(ROOT / "slurm" / "merge_job.sbatch"), *args], env=env, capture_output=True,
                       text=True, timeout=30)
    assert p.returncode != 0 and needle in p.stderr, (p.returncode, p.stderr)
    assert not (tmp_path / "m.h5").exists()


# ---- item 2 --------------------------------------------------------------------------------------------------


def test_concurrent_exports_to_one_out(ref, tmp_path, monkeypatch):
    pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    import sys

    import xarray as xr

    from gapsweep.sweep import dataset

    other_job = tmp_path / "other.toml"
    other_job.write_text(JOB.read_text().replace('name = "faults-units"', 'name = "faults-other"'))
    other = tmp_path / "o.h5"
    run_job(other_job, other)
    out = tmp_path / "x.nc"
    second: list[subprocess.CompletedProcess] = []
    real = dataset._write_nc

    def write_then_race(ds, tmp, outp):
        real(ds, tmp, outp)  # this export's file is written under its temporary name ...
        # ... and before it is moved into place, a second export of another store to the same --out runs to its end
        env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
        second.append(subprocess.run([sys.executable, "-m", "gapsweep", "export", str(other), "--out", str(out),
                                      "--overwrite"], env=env, capture_output=True, text=True, timeout=120))

    monkeypatch.setattr(dataset, "_write_nc", write_then_race)
    dataset.export_netcdf(ref, out)
    (p,) = second
    assert p.returncode != 0 and "lease" in p.stderr and "Traceback" not in p.stderr, p.stderr
    with xr.open_dataset(out, engine="h5netcdf") as ds:
        assert ds.attrs["gapsweep_job_name"] == "faults-units"  # the data of the export that exited 0
    assert sorted(x.name for x in tmp_path.iterdir() if x.name.startswith(".x.nc")) == []  # no temporary left
    # afterwards the other export may replace it (--overwrite of an earlier export), with its own data
    monkeypatch.setattr(dataset, "_write_nc", real)
    dataset.export_netcdf(other, out, overwrite=True)
    with xr.open_dataset(out, engine="h5netcdf") as ds:
        assert ds.attrs["gapsweep_job_name"] == "faults-other"


# ---- item 7 --------------------------------------------------------------------------------------------------


def _dead_pid() -> int:
    p = subprocess.Popen(["true"])
    p.wait()
    return p.pid


def _stale_lease(store_path: Path) -> None:
    import socket

    from gapsweep.sweep import lease

    lease.lease_path(store_path).write_text(json.dumps({"host": socket.gethostname(), "pid": _dead_pid(),
                                                        "run_id": "deadbeef0000", "started": "x"}))


@pytest.mark.parametrize("holder", ["none", "dead"])
def test_status_removes_a_killed_writers_temporary_file(ref, tmp_path, capsys, holder):
    path = copy_store(ref, tmp_path)
    left = tmp_path / f".s.h5.tmp-{_dead_pid()}"
    left.write_bytes(b"\0" * 4096)
    if holder == "dead":
        _stale_lease(path)
    rc, out, err = cli_run(capsys, "status", path)
    assert rc == 0 and not left.exists(), out + err
    assert f"removed: {left.name}" in out and left.name in err, out + err
    left.write_bytes(b"x")
    rc, out, _ = cli_run(capsys, "status", "--json", path)
    assert json.loads(out)["removed_leftovers"] == [left.name] and not left.exists()


def test_a_live_lease_keeps_its_temporary_file(ref, tmp_path, capsys):
    from gapsweep.sweep import lease

    path = copy_store(ref, tmp_path)
    mine = tmp_path / ".s.h5.tmp-0123456789ab"
    mine.write_bytes(b"x")
    with lease.acquire(path, purpose="test"):
        rc, out, _ = cli_run(capsys, "status", path)
        assert rc == 0 and mine.exists() and "removed" not in out


def test_merge_export_and_run_remove_leftovers(ref, tmp_path):
    """Each under its own lease: the file of a killed merge beside --out, of a killed export, of a killed
    creation beside the store that --resume opens."""
    from gapsweep.sweep import merge

    m = tmp_path / "m.h5"
    left = tmp_path / f".m.h5.tmp-{_dead_pid()}"
    left.write_bytes(b"x" * 100)
    merge.merge([ref], m)
    assert not left.exists() and m.exists()
    path = copy_store(ref, tmp_path)
    left = tmp_path / ".s.h5.tmp-abcdef012345"
    left.write_bytes(b"x")
    run_job(JOB, path, resume=True)
    assert not left.exists()
    import importlib.util

    if importlib.util.find_spec("h5netcdf") and importlib.util.find_spec("xarray"):
        from gapsweep.sweep import dataset

        left = tmp_path / f".x.nc.tmp-{_dead_pid()}-00ff00ff"
        left.write_bytes(b"x")
        dataset.export_netcdf(ref, tmp_path / "x.nc")
        assert not left.exists()


# ---- item 8 --------------------------------------------------------------------------------------------------


@pytest.fixture()
def writer_lease():
    """A lease of another live process (a child that waits), as a running writer holds it; the lease of this
    process would not count (a merge reading its own output must get its own errors)."""
    import socket
    import sys

    from gapsweep.sweep import lease

    child = subprocess.Popen([sys.executable, "-c", "import sys; sys.stdin.read()"], stdin=subprocess.PIPE)
    made = []

    def take(path: Path) -> None:
        lp = lease.lease_path(path)
        lp.write_text(json.dumps({"host": socket.gethostname(), "pid": child.pid, "run_id": "0123456789ab",
                                  "started": "now", "purpose": "run"}))
        made.append(lp)

    yield take
    child.stdin.close()
    child.wait()
    for lp in made:
        lp.unlink(missing_ok=True)


def test_reader_of_a_store_being_written_retries(ref, tmp_path, monkeypatch, writer_lease):
    from gapsweep.sweep import lease, storecheck
    from gapsweep.sweep import store as st

    path = copy_store(ref, tmp_path)
    monkeypatch.setattr(st, "RETRY_DELAYS", (0.0, 0.0, 0.0))
    real, calls = storecheck.check, []

    def torn(f, p, **kw):  # the first two reads meet metadata being written
        calls.append(1)
        if len(calls) <= 2:
            raise st.StoreError(f"store {p}: not a readable HDF5 file (bad object header): truncated or damaged")
        return real(f, p, **kw)

    monkeypatch.setattr(st.storecheck, "check", torn)
    with lease.acquire(path, purpose="test"):  # this process's own lease: its errors are its own, no retry
        with pytest.raises(st.StoreError, match="truncated or damaged"):
            st.read(path)
    calls.clear()
    writer_lease(path)
    assert (st.read(path).status == "done").all() and len(calls) == 3
    calls.clear()
    assert "2 tasks" in st.status(path)  # nested readers: one retry loop
    lease.lease_path(path).unlink()
    calls.clear()
    with pytest.raises(st.StoreError, match="truncated or damaged"):  # no writer: the damage is named
        st.read(path)


def test_persistent_failure_while_written_says_being_written(ref, tmp_path, monkeypatch, writer_lease):
    from gapsweep.sweep import lease
    from gapsweep.sweep import store as st

    path = copy_store(ref, tmp_path)
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])  # what a reader may meet: a file whose metadata is not all there
    monkeypatch.setattr(st, "RETRY_DELAYS", (0.0,))
    writer_lease(path)
    with pytest.raises(st.StoreError) as e:
        st.read(path)
    lease.lease_path(path).unlink()
    assert "being written by" in str(e.value) and "damaged" not in str(e.value).split("(`gapsweep status`")[0]
    with pytest.raises(st.StoreError, match="truncated or damaged"):
        st.read(path)


# ---- item 3 --------------------------------------------------------------------------------------------------


def test_merge_under_a_file_size_limit(tmp_path):
    """A pending store of 3,000 rows (~3 MB, made without running anything) merged under a 1 MB file-size
    limit."""
    import resource
    import sys

    from gapsweep.sweep import provenance, tasks
    from gapsweep.sweep.store import Store

    text = JOB.read_text().replace("sigma0 = [1e-2, 1e-1]", "sigma0 = [" + ", ".join(
        f"{1e-3 * (1 + k):.6g}" for k in range(3000)) + "]")
    job = tmp_path / "big.toml"
    job.write_text(text)
    js = spec.load(job)
    ts = tasks.expand(js)
    shard = tmp_path / "big.h5"
    Store.create(shard, ts, provenance.store_attrs(js), js.histogram["bins"]).close()
    assert len(ts) == 3000 and shard.stat().st_size > 2_000_000
    before = shard.read_bytes()
    limit = 1 << 20

    def cap() -> None:
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    out = tmp_path / "m.h5"
    p = subprocess.run([sys.executable, "-m", "gapsweep", "merge", str(shard), "--out", str(out)], env=env,
                       capture_output=True, text=True, timeout=120, preexec_fn=cap)
    lines = [x for x in p.stderr.splitlines() if x.strip()]
    assert p.returncode == 1 and len(lines) == 1 and "merge --out" in lines[0], (p.returncode, p.stderr)
    assert "nothing was written" in lines[0]
    assert not out.exists() and shard.read_bytes() == before
    assert sorted(x.name for x in tmp_path.iterdir()) == ["big.h5", "big.toml"]  # no temporary, no lease left


def _metadata_regions(path: Path) -> list[tuple[int, int]]:
    """(start, length) of HDF5 metadata in ``path``: every object header, the global heap collection (the
    attributes' strings), B-tree nodes, symbol-table nodes and local heaps (found by their signatures)."""
    data = path.read_bytes()
    out = []
    with h5py.File(path, "r") as f:
        names = ["/"]
        f.visit(names.append)
        for k in names:
            out.append((h5py.h5o.get_info(f[k].id).addr, 160))
    for sig, n in ((b"GCOL", 1024), (b"TREE", 64), (b"SNOD", 64), (b"HEAP", 32)):
        start = 0
        while (i := data.find(sig, start)) >= 0:
            out.append((i, n))
            start = i + 1
    return out


def test_byte_flips_in_hdf5_metadata_never_crash(ref, tmp_path, capsys):
    regions = _metadata_regions(ref)
    rng = np.random.default_rng(40)
    data = ref.read_bytes()
    outcomes, seen = {0: 0, 1: 0}, []
    for k in range(10):
        start, n = regions[int(rng.integers(len(regions)))]
        off = start + int(rng.integers(n))
        b = bytearray(data)
        b[off] ^= 1 << int(rng.integers(8))
        path = tmp_path / f"f{k}.h5"
        path.write_bytes(bytes(b))
        for cmd in (["status", "--json", path], ["merge", path, "--out", tmp_path / f"m{k}.h5"]):
            rc, _, err = cli_run(capsys, *cmd)
            lines = [x for x in err.splitlines() if x.strip() and "warning" not in x.lower()]
            assert rc in (0, 1) and "Traceback" not in err, (k, off, cmd, rc, err)
            if rc:
                assert len([x for x in lines if x.startswith("gapsweep: store") or "merge" in x]) >= 1, err
            outcomes[rc] += 1
            seen.append((k, off, cmd[0], rc))
        assert path.read_bytes() == bytes(b)  # a reader changes nothing
    assert outcomes[1] > 0, seen  # the flips do reach the library (not all harmless)
