"""The challenge's law (interaction "hard_wall_adhesive") against tamaas 2.9 and ContactMechanics + Adhesion on
the cases of tests/test_peers_challenge.py (same surfaces, laws and loads): per case and load, the relative
difference of the mean gap and whether the contact pixels are identical, for gapsweep's own load path and for a
start from the peer's field. Writes benchmarks/results/challenge/peers_cpu.json. Run with the peers' venv:

    PYTHONPATH=. /work/peers/bin/python benchmarks/peers_challenge.py
"""

from __future__ import annotations

import datetime
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))

import sys as _sys  # noqa: E402
from pathlib import Path as _Path  # noqa: E402

import test_peers_challenge as T  # noqa: E402

_sys.path.insert(0, str(_Path(__file__).resolve().parent))
import _record  # noqa: E402

# the code this benchmark measures: a result measured before a later change to it is stale
# (scripts/check_docs.py)
CODE_PATHS = ['gapsweep/gfmd/_bounded.py', 'gapsweep/gfmd/interactions/hard_wall_adhesive.py']

def main() -> None:
    rows = []
    for peer, cases in (("tamaas", T.CASES), ("contactmechanics", T.CASES + T.CM_ODD)):
        for nx, ny, box, seed, h_rms, mu, rdx, fractions, offsets in cases:
            h = T.periodic_map(nx, ny, *box, seed, h_rms=h_rms)
            work, rho = T.law(nx, box[0], mu, rdx)
            if peer == "tamaas":
                theirs = T.tamaas_at_gap(h, box, work, rho, [f * h_rms for f in fractions])
            else:
                theirs = T.contactmechanics_at_offset(h, box, work, rho, [f * h_rms for f in offsets])
            multi = T.MULTISTABLE.get((peer, seed), ())
            for i, (sigma0, gap, field) in enumerate(theirs):
                for start in ("own", "peer"):
                    if start == "own" and i in multi:
                        continue
                    t = time.perf_counter()
                    r = T.ours(h, box, work, rho, sigma0, None if start == "own" else field)
                    rows.append({"peer": peer, "nx": nx, "ny": ny, "seed": seed, "mu_rho": mu, "rho_dx": rdx,
                                 "sigma0": sigma0, "start": start, "mean_gap_peer": gap, "mean_gap": r.mean_gap,
                                 "gap_rel_diff": abs(r.mean_gap - gap) / gap,
                                 "contact_pixels_differ": int(np.sum((r.gap <= 0) != (field <= 0))),
                                 "contact_area": r.contact_area, "iterations": r.iterations,
                                 "wall_s": time.perf_counter() - t})
    commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True, text=True).stdout.strip()
    out = {"command": "PYTHONPATH=. /work/peers/bin/python benchmarks/peers_challenge.py", "commit": commit,
           "machine": f"{platform.node()} ({platform.processor() or platform.machine()}), 2 shared CPU cores",
           "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"), "rows": rows}
    path = ROOT / "benchmarks/results/challenge/peers_cpu.json"
    path.write_text(json.dumps(out, indent=1) + "\n")
    print(path, len(rows), "rows; max gap_rel_diff", max(r["gap_rel_diff"] for r in rows),
          "; max pixels differ", max(r["contact_pixels_differ"] for r in rows))


if __name__ == "__main__":
    _record.track(CODE_PATHS)
    main()
