"""Cost of the row checksums (issue 19: at most 2 % of a small-task sweep's time).

Runs the sweep-overhead job (``benchmarks/bench_sweep_overhead.py``: N field-theory tasks of ~0.2 ms, the
smallest tasks a sweep has, so the store's per-row work weighs most) in one process, alternating runs that compute
each row's checksum with runs where the checksum function is replaced by a constant (everything else -- the same
one write per row -- unchanged), and reports the median wall time of each and their ratio.

    python benchmarks/bench_checksum.py [--tasks 4000] [--pairs 5]
"""

from __future__ import annotations

import argparse
import importlib.util
import statistics
import sys as _sys
import tempfile
import time
import timeit
from pathlib import Path
from pathlib import Path as _Path

from gapsweep.sweep import runner, store

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/sweep/store.py', 'gapsweep/sweep/storecheck.py', 'gapsweep/sweep/schema.py',
              'gapsweep/sweep/runner.py']


def _row():
    import numpy as np

    from gapsweep.sweep.schema import RESULT_DTYPE, TASK_DTYPE

    nan = (np.full(65, np.nan), np.full(64, np.nan))
    return np.zeros(1, TASK_DTYPE)[0], np.zeros(1, RESULT_DTYPE)[0], (*nan, *nan)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--tasks", type=int, default=4000)
    ap.add_argument("--pairs", type=int, default=5)
    args = ap.parse_args()
    spec = importlib.util.spec_from_file_location("ovh", Path(__file__).with_name("bench_sweep_overhead.py"))
    ovh = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ovh)
    tmp = Path(tempfile.mkdtemp(prefix="gapsweep-ck-"))
    job = tmp / "job.toml"
    job.write_text(ovh.SPEC.format(num=args.tasks // 4))
    real = store.row_checksum
    times: dict[str, list[float]] = {"checksums": [], "constant": []}
    runner.run(job, tmp / "warm.h5", progress="none", mpi="off")  # imports, caches
    for k in range(args.pairs):
        for name in ("checksums", "constant") if k % 2 == 0 else ("constant", "checksums"):
            store.row_checksum = real if name == "checksums" else (lambda *a: 1)
            t0 = time.perf_counter()
            runner.run(job, tmp / f"{name}{k}.h5", progress="none", mpi="off")
            times[name].append(time.perf_counter() - t0)
    store.row_checksum = real
    a, b = statistics.median(times["checksums"]), statistics.median(times["constant"])
    pair = statistics.median(x / y for x, y in zip(times["checksums"], times["constant"]))
    print(f"{args.tasks} theory tasks, {args.pairs} runs each (alternating): with checksums {a:.3f} s "
          f"({1e3 * a / args.tasks:.3f} ms/task), checksum constant {b:.3f} s; ratio of medians {a / b:.4f} "
          f"(+{100 * (a / b - 1):.1f} %), median of the pairs' ratios {pair:.4f}")
    row = _row()
    t = timeit.timeit(lambda: store.row_checksum(*row), number=20000) / 20000
    print(f"one row's checksum (64 bins): {1e6 * t:.1f} us = {100 * t / (a / args.tasks):.2f} % of a task's "
          "time in this sweep")
    print("per run:", {k: [round(x, 3) for x in v] for k, v in times.items()})


if __name__ == "__main__":
    _record.track(CODE_PATHS, header=True)
    main()
