"""Hard-wall iteration counts of the CG restart rule (issue 39, item 1; docs/benchmarks_gfmd.md, "Issue 39"):
"mpcg" with the rule of gapsweep.gfmd._constrained (``_KEEP``: restart only when more than that fraction of the
contact set re-entered) against the Polonsky-Keer rule (restart at every re-entry, ``_KEEP = 0``), side by side on
surfaces the rule was not tuned on (it was tuned on N = 1024, seed 2, H 0.3 / 0.8, sigma0 1e-3 ... 0.1).
Iterations are deterministic; no timing here (bench_contact.py times it against tamaas).

    OMP_NUM_THREADS=1 python benchmarks/bench_hardwall_iters.py --out OUT [--n 1024] [--free-n 512]
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import subprocess
import sys
import warnings
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from gapsweep.gfmd import _constrained, solve
from gapsweep.surface import self_affine

CASES = [(0.5, 3), (0.8, 4), (0.3, 5)]  # (H, seed), held out
LOADS = [5e-3, 3e-2, 0.2]



import sys as _sys  # noqa: E402
from pathlib import Path as _Path  # noqa: E402

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record  # noqa: E402

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd/_constrained.py', 'gapsweep/gfmd/_constrained_ops.py']


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, required=True)
    ap.add_argument("--n", type=int, default=1024)
    ap.add_argument("--free-n", type=int, default=512)
    ap.add_argument("--name", default="issue39_restart_iters")
    a = ap.parse_args()
    warnings.simplefilter("ignore")
    keep = _constrained._KEEP
    rows = []
    for periodic, n in ((True, a.n), (False, a.free_n)):
        for hurst, seed in CASES:
            h = self_affine(n, hurst, lambda_l=0.25, lambda_s=2.5e-3 if n >= 1024 else 8 / n, rms_slope=1.0, seed=seed)
            for s0 in LOADS:
                row = {"periodic": periodic, "n": n, "H": hurst, "seed": seed, "sigma0": s0}
                for label, k in (("restart_every", 0.0), ("restart_rule", keep)):
                    _constrained._KEEP = k
                    r = solve(h, sigma0=s0, interaction="hard_wall", method="mpcg", tol=1e-8, max_iter=3000,
                              periodic=periodic)
                    row[f"{label}_iters"] = r.iterations
                    row[f"{label}_coarse"] = r.diagnostics["coarse_iterations"]
                    row[f"{label}_converged"] = r.converged
                    row[f"{label}_mean_gap"] = r.mean_gap
                _constrained._KEEP = keep
                row["fine_iter_ratio"] = row["restart_every_iters"] / row["restart_rule_iters"]
                row["gap_rel_diff"] = abs(row["restart_rule_mean_gap"] / row["restart_every_mean_gap"] - 1)
                rows.append(row)
                print(row, flush=True)
    commit = subprocess.run(["git", "rev-parse", "HEAD"], capture_output=True, text=True,
                            cwd=Path(__file__).resolve().parents[1]).stdout.strip()
    meta = {"host": platform.node(), "machine": platform.machine(), "python": platform.python_version(),
            "commit": commit, "keep": keep, "command": " ".join(sys.argv),
            "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")}
    a.out.mkdir(parents=True, exist_ok=True)
    (a.out / f"{a.name}.json").write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
