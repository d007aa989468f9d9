"""Worker of tests/mpi/test_collective.py, run as ``mpiexec -n P python tests/mpi/slab_worker.py JOB OUT``: the
memory of a distributed job's surface and kept fields per rank (numpy arrays traced by tracemalloc), written by
rank 0 as JSON to OUT. Not a test module itself (no ``test_`` prefix).

* surface: ``Context.surface_rows`` of the job's first GFMD task (made in place, gapsweep.sweep.slabs, with its
  h_rms and g_rms): the peak while it is made and what stays held, in units of the whole surface (8 n^2 bytes),
  and whether the rows equal ``self_affine``'s bit for bit.
* fields: rank 0's peak while ``fields.write_field_rows`` (rank-0 writer) writes four fields of the grid with
  row chunks of ``CHUNK`` bytes, in bytes, beside the size of one whole field; whether the files of both writers
  (mpio where h5py has MPI) hold the fields bit for bit."""

from __future__ import annotations

import json
import sys
import tempfile
import tracemalloc

import numpy as np
from mpi4py import MPI

from gapsweep import gfmd
from gapsweep.surfaces.synthetic import self_affine
from gapsweep.sweep import fields, runner, slabs
from gapsweep.sweep import spec as specmod
from gapsweep.sweep.context import Context

comm = MPI.COMM_WORLD
CHUNK = 64 << 10

t = next(x for x in runner._select(specmod.load(sys.argv[1]), None)[0] if x.method == "gfmd")
n = t.n
whole = 8.0 * n * n
ctx = Context(rank=comm.Get_rank())
tracemalloc.start()
base = tracemalloc.get_traced_memory()[0]
h = ctx.surface_rows(t, n, comm)
h_rms, g_rms = ctx.surface_rows_rms(t, n, comm)
# held: the blocks of >= 4 KiB that stay allocated (arrays), the import machinery left out: a first import of a
# module, as on a fresh clone, allocates ~86 kB of code objects and a few hundred bytes of small caches that are
# not the surface's (seen on the plain-user stack: 0.56 and 0.5102 of a map held on 2 ranks otherwise)
_imports = [tracemalloc.Filter(False, "<frozen importlib._bootstrap>"),
            tracemalloc.Filter(False, "<frozen importlib._bootstrap_external>")]
peak = tracemalloc.get_traced_memory()[1] - base
held = sum(tr.size for tr in tracemalloc.take_snapshot().filter_traces(_imports).traces if tr.size >= 4096)
tracemalloc.stop()
ref = self_affine(n, t.hurst, seed=t.seed, **t.surface_params()) if comm.Get_rank() == 0 else None
ref = comm.bcast(ref, root=0)
same = bool(np.array_equal(h, ref[gfmd.slab_rows(n, comm)]))
del ref

slabs.CHUNK_BYTES = CHUNK
rows = {k: np.asarray(h) + i for i, k in enumerate(("displacement", "gap", "height", "pressure"))}
d = comm.bcast(tempfile.mkdtemp() if comm.Get_rank() == 0 else None, root=0)
tracemalloc.start()
base = tracemalloc.get_traced_memory()[0]
fields.write_field_rows(d, "0123456789abcdef", rows, shape=(n, n), comm=comm, writer="rank0", length=1.0,
                        attrs={"n": n})
write_peak = tracemalloc.get_traced_memory()[1] - base
tracemalloc.stop()
import h5py  # noqa: E402

if h5py.get_config().mpi:  # the mpio writer: the same file contents
    fields.write_field_rows(d, "fedcba9876543210", rows, shape=(n, n), comm=comm, writer="mpio", length=1.0,
                            attrs={"n": n})
got = comm.gather((peak / whole, held / whole, same, write_peak), root=0)
if comm.Get_rank() == 0:
    h = self_affine(n, t.hurst, seed=t.seed, **t.surface_params())
    written = True
    for name in ("0123456789abcdef", "fedcba9876543210")[:1 + h5py.get_config().mpi]:
        with h5py.File(f"{d}/{name}.nc") as f:
            written &= all(bool(np.array_equal(f[k][...], h + i)) for i, k in
                           enumerate(("displacement", "gap", "height", "pressure")))
    out = {"ranks": comm.Get_size(), "n": n, "surface_peak": max(g[0] for g in got),
           "surface_held": max(g[1] for g in got), "identical": all(g[2] for g in got),
           "rank0_write_peak": got[0][3], "other_write_peak": max(g[3] for g in got[1:]), "field_bytes": whole,
           "chunk_bytes": CHUNK, "written": written}
    with open(sys.argv[2], "w") as f:
        json.dump(out, f, indent=1)
