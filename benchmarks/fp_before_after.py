"""Fokker-Planck wall time and moments on its default arguments, for a before/after comparison (issue 9.1): the three
benchmarks/bench_fp.py cases plus the M7 stiff case at sigma0 = 1 and 10 (best of 5 wall times). Run it once per tree:

    PYTHONPATH=<tree> python benchmarks/fp_before_after.py
"""

from __future__ import annotations

import math
import sys
import time
from pathlib import Path

from gapsweep import fokker_planck

sys.path.insert(0, str(Path(__file__).resolve().parent))
import sys as _sys
from pathlib import Path as _Path

from bench_fp import PARAMS

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gapdist/fokker_planck.py']

STIFF = dict(hurst=0.3, h_rms=2.34e-3, gamma0=1e-3, lambda_l=0.25, lambda_s=2.5e-3, rho=5e-4)


def main() -> None:
    cases = dict(PARAMS)
    cases["stiff_s0_1"] = (STIFF, 1.0, 1.0)
    cases["stiff_s0_10"] = (STIFF, 10.0, 1.0)
    for name, (p, s0, c2) in cases.items():
        fokker_planck.solve(s0, c2=c2, **p)  # warm
        times = []
        for _ in range(5):  # best of 5: the machine is shared
            t = time.perf_counter()
            r = fokker_planck.solve(s0, c2=c2, **p)
            times.append(time.perf_counter() - t)
        t = min(times)
        err = getattr(r, "error", float("nan"))
        print(f"{name}: {t:.3f} s, cells {r.y.size}, steps {r.n_steps}, mean {r.mean():.6g}, "
              f"sd {math.sqrt(r.variance()):.5g}, status {r.status}, error {err:.2g}")


if __name__ == "__main__":
    _record.track(CODE_PATHS, header=True)
    main()
