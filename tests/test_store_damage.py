"""Issue 40 item 1: damage the rows survive never blocks them. One flipped bit in a provenance attribute
(``created``, ``versions``, ``git_commit``, ...), in the job spec's attributes (``spec_text``, ``units``) or in the
checksum record itself (``integrity``) made status, ``status --json``, export, merge (``--skip-damaged`` too) and
``--resume`` refuse, and resume offered ``--overwrite``, although every row verifies on its own checksum. Now
every reader reports the damage and goes on, provenance is rebuilt (marked as lost), the spec's attributes are
restored from the job file by ``--resume`` or ``gapsweep repair --job`` after checking every task row, and no
message offers ``--overwrite``. All in-process (the CLI through ``cli.main``)."""

from __future__ import annotations

import json
from pathlib import Path

import h5py
import pytest

from gapsweep import store
from gapsweep.sweep import costleft, merge, repair, runner, storecheck
from tests.storekit import UNITS_JOB, cli_run, copy_store, flip_attr, run_job, units_store

JOB = UNITS_JOB
PROVENANCE = ("created", "versions", "git_commit", "gapsweep_version", "finished", "job_name")
SPEC = ("spec_text", "units", "spec_sha256")


@pytest.fixture(scope="module")
def ref(tmp_path_factory) -> Path:
    return units_store(tmp_path_factory, "damage")


def _verified(path: Path) -> storecheck.Report:
    with store.open_read(path, check=False) as f:
        return storecheck.check(f, path)


@pytest.mark.parametrize("name", [*PROVENANCE, *SPEC, "integrity"])
def test_readers_report_and_go_on(ref, tmp_path, capsys, name):
    """status, status --json and store.read report the damage and go on; the store is not changed."""
    path = copy_store(ref, tmp_path)
    flip_attr(path, name)
    before = path.read_bytes()
    rep = _verified(path)
    assert rep.damaged == [] and rep.attrs_need_repair
    if name in PROVENANCE:
        assert rep.provenance_damaged == [name]
    elif name in SPEC:
        assert rep.spec_damaged == [name]
    else:
        assert rep.integrity_damaged
    rc, out, err = cli_run(capsys, "status", path)
    assert rc == 0 and "--overwrite" not in out + err, out + err
    assert (f"{name!r}" in out) and "2 tasks" in out, out
    rc, out, _ = cli_run(capsys, "status", "--json", path)
    js = json.loads(out)
    assert rc == 0 and js["total"] == {"done": 2} and any(name in x for x in js["check"]), js
    assert (store.read(path).status == "done").all()
    assert path.read_bytes() == before


@pytest.mark.parametrize("name", [*PROVENANCE, *SPEC, "integrity"])
def test_export_and_merge_go_on(ref, tmp_path, capsys, name):
    """export and merge (also --skip-damaged) of a store beside an intact shard: the rows of both are kept;
    the export's units are the job's (MPa) even where the attribute is damaged (from the spec text), and a
    damaged attribute is not copied into the export."""
    pytest.importorskip("xarray")
    pytest.importorskip("h5netcdf")
    path = copy_store(ref, tmp_path)
    flip_attr(path, name)
    rc, _, err = cli_run(capsys, "export", path, "--out", tmp_path / "x.nc")
    assert rc == 0, err
    import xarray as xr

    with xr.open_dataset(tmp_path / "x.nc", engine="h5netcdf") as ds:
        assert json.loads(ds.attrs["gapsweep_units"])["pressure"] == "MPa"
        if name in PROVENANCE:
            assert f"gapsweep_{name}" not in ds.attrs or name == "gapsweep_version"
            assert name in json.loads(ds.attrs["gapsweep_damaged_attributes"])
    other = copy_store(ref, tmp_path, "o.h5")
    for extra in ([], ["--skip-damaged"]):
        out_p = tmp_path / f"m{len(extra)}.h5"
        rc, _, err = cli_run(capsys, "merge", path, other, "--out", out_p, *extra)
        assert rc == 0, err
        assert store.diff(out_p, ref) == [] and _verified(out_p).attrs_need_repair is False


def test_merge_of_only_shards_with_damaged_spec_names_repair(ref, tmp_path, capsys):
    """With no shard whose spec verifies, merge cannot know the job: it says `gapsweep repair --job`, never
    --overwrite; after the repair the merge works."""
    path = copy_store(ref, tmp_path)
    flip_attr(path, "spec_text")
    rc, out, err = cli_run(capsys, "merge", path, "--out", tmp_path / "m.h5")
    assert rc == 1 and "gapsweep repair" in err and "--overwrite" not in err, err
    assert not (tmp_path / "m.h5").exists()
    rc, out, err = cli_run(capsys, "repair", path, "--job", JOB)
    assert rc == 0 and "restored" in out, out + err
    assert not _verified(path).attrs_need_repair
    rc, out, err = cli_run(capsys, "merge", path, "--out", tmp_path / "m.h5")
    assert rc == 0, err


@pytest.mark.parametrize("name", [*PROVENANCE, *SPEC, "integrity"])
def test_resume_restores(ref, tmp_path, name):
    """--resume with the job file mends every attribute and keeps every row; provenance is marked as lost."""
    path = copy_store(ref, tmp_path)
    flip_attr(path, name)
    s = run_job(JOB, path, resume=True)
    assert s["todo"] == 0
    rep = _verified(path)
    assert not rep.attrs_need_repair and rep.runs_damaged is None
    assert store.diff(path, ref) == []
    a = store.read_attrs(path)
    if name in ("created", "git_commit"):  # (finished: the resume sets it again)
        assert a[name].startswith("unknown: the attribute was damaged")
    if name in SPEC:
        with h5py.File(ref) as f:
            assert a[name] == (f.attrs[name].decode() if isinstance(f.attrs[name], bytes) else f.attrs[name])


def test_without_resume_no_overwrite_offered(ref, tmp_path):
    path = copy_store(ref, tmp_path)
    flip_attr(path, "spec_text")
    with pytest.raises(runner.RunError) as e:
        run_job(JOB, path)
    assert "--resume" in str(e.value) and "--overwrite" not in str(e.value)


def test_resume_with_another_job_is_refused(ref, tmp_path):
    """The spec attributes are restored only from the store's own job: another job's task rows differ."""
    path = copy_store(ref, tmp_path)
    flip_attr(path, "spec_text")
    other = tmp_path / "other.toml"
    other.write_text(JOB.read_text().replace("sigma0 = [1e-2, 1e-1]", "sigma0 = [1e-2, 2e-1]"))
    before = path.read_bytes()
    with pytest.raises(runner.RunError, match="not the store's"):
        run_job(other, path, resume=True)
    with pytest.raises(store.StoreError, match="not this store's"):
        repair.repair(path, other)
    assert path.read_bytes() == before


@pytest.mark.parametrize("name", ["created", "versions", "units", "integrity"])
def test_repair_without_job(ref, tmp_path, name):
    """Provenance is rebuilt; units and the checksum record come back from the store's own spec text (which
    still matches its hash and the task table) without a job file."""
    path = copy_store(ref, tmp_path)
    flip_attr(path, name)
    lines = repair.repair(path)
    assert any("rebuilt" in x or "restored" in x for x in lines), lines
    assert not _verified(path).attrs_need_repair
    assert store.diff(path, ref) == []


def test_repair_restores_the_job_name_from_the_spec(ref, tmp_path, capsys):
    path = copy_store(ref, tmp_path)
    flip_attr(path, "job_name")
    rc, out, err = cli_run(capsys, "repair", path)
    assert rc == 0 and "restored from the spec: job_name" in out, out + err
    assert store.read_attrs(path)["job_name"] == "faults-units" and not _verified(path).attrs_need_repair


def test_repair_of_spec_text_needs_the_job(ref, tmp_path):
    path = copy_store(ref, tmp_path)
    flip_attr(path, "spec_text")
    with pytest.raises(store.StoreError, match="pass --job"):
        repair.repair(path)
    with pytest.raises(store.StoreError, match="damaged"):
        costleft.cost_left(path)
    assert costleft.summary(path)["cost_left"]["error"]


def test_format_damage_still_refuses(ref, tmp_path):
    """Damage to what the rows cannot survive (the format version names the layout) still refuses."""
    path = copy_store(ref, tmp_path)
    flip_attr(path, "format_version")
    with pytest.raises(store.StoreError, match="format_version"):
        store.read(path)


def test_merge_skip_damaged_with_a_damaged_shard_spec(ref, tmp_path, capsys):
    """merge.merge in-process: a shard with damaged spec text merged beside an intact one."""
    a = copy_store(ref, tmp_path, "a.h5")
    flip_attr(a, "spec_text")
    counts = merge.merge([a, copy_store(ref, tmp_path, "b.h5")], tmp_path / "m.h5", skip_damaged=True)
    assert counts["done"] == 2 and counts["damaged"] == 0
