"""benchmarks/challenge_refine.py (the refinement study of issue 37 item 4, docs/challenge.md) on the CPU at a
small size, in process: the challenge's law and constants on grids 32 -> 64 -> 128 of a 0.195 um box (pixel 6.1
down to 1.5 nm, mu_rho 1.7 down to 0.84), the reference load along its loading path. Every solve converged; the
table's numbers are those of its solves (area and mean gap of the reference solve, the stiffness their central
difference); a study whose solve is capped is reported as failed (exit status 1) without numbers."""

from __future__ import annotations

import importlib.util
import json
import math
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def refine():
    spec = importlib.util.spec_from_file_location("challenge_refine", ROOT / "benchmarks" / "challenge_refine.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_refinement_table_comes_from_converged_solves(refine, tmp_path):
    out = tmp_path / "refine.json"
    args = ["--n", "32", "64", "128", "--box", "0.1953125", "--ramp", "1", "--out", str(out)]
    assert refine.main(args) == 0
    d = json.loads(out.read_text())
    assert d["ok"] and [g["n"] for g in d["grids"]] == [32, 64, 128] and all(g["complete"] for g in d["grids"])
    assert len(d["solves"]) == 3 * 4 and all(s["status"] == "converged" for s in d["solves"])
    assert [s["from"] for s in d["solves"][:4]] == ["flat", "previous load", "reference", "reference"]
    for g in d["grids"]:
        s = {x["role"]: x for x in d["solves"] if x["n"] == g["n"]}
        ref, lo, hi = s["path 1"], s["minus"], s["plus"]
        assert ref["sigma0_MPa"] == 0.25 and g["contact_area"] == ref["contact_area"] > 0
        assert g["mean_gap_um"] == ref["mean_gap_um"] > 0
        k = -(hi["sigma0_MPa"] - lo["sigma0_MPa"]) / (hi["mean_gap_um"] - lo["mean_gap_um"])
        assert g["stiffness_MPa_per_um"] == pytest.approx(k, rel=1e-12) and k > 0
        assert g["mu_rho"] == pytest.approx(0.8435 * math.sqrt(128 / g["n"]), rel=1e-3)
    ch = [c for c in d["changes"] if "from_n" in c]
    assert [(c["from_n"], c["to_n"]) for c in ch] == [(32, 64), (64, 128)]
    a, b = d["grids"][1], d["grids"][2]
    assert ch[1]["rel_change_mean_gap_um"] == pytest.approx(abs(b["mean_gap_um"] - a["mean_gap_um"]) / b["mean_gap_um"])
    assert sum("order_of" in c for c in d["changes"]) == 3


def test_a_capped_solve_fails_the_study(refine, tmp_path):
    out = tmp_path / "refine.json"
    assert refine.main(["--n", "32", "64", "--box", "0.1953125", "--max-iter", "3", "--out", str(out)]) == 1
    d = json.loads(out.read_text())
    assert not d["ok"] and d["solves"][-1]["status"] == "max_iter"
    assert d["grids"] == [{**d["grids"][0], "complete": False}] and "contact_area" not in d["grids"][0]
    assert d["changes"] == []
    with pytest.raises(SystemExit):
        refine.main(["--n", "64", "32"])
