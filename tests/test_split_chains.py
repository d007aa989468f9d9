"""``[methods.gfmd] split_chains = L`` (issue 38): a warm-started pressure chain cut into segments of at most L
pressures, each a unit of its own that starts cold -- the cut fixed by the job (never by the ranks), each row's
start in its task id and chain key, the results within the solver's tolerance of the uncut chain's (an
independent path to the same equilibrium), the first segment's rows bit for bit the uncut chain's."""

from __future__ import annotations

import pytest

from gapsweep import store
from gapsweep.sweep import runner
from gapsweep.sweep import spec as specmod
from gapsweep.sweep import tasks as T
from gapsweep.sweep.schema import SpecError

JOB = """
[job]
name = "split"
[grid]
hurst = [0.6]
{rho}sigma0 = {{min = 1e-3, max = 0.3, num = 5, scale = "log"}}
seeds = [3, 7]
[surface]
lambda_l = 0.25
lambda_s = 0.0625
rms_slope = 1.0
{law}
[material]
{material}
[histogram]
bins = 16
[methods.gfmd]
n = 64
tol = 1e-6
backend = "numpy"
{extra}
"""
EXP = {"rho": "rho = [2e-2]\n", "law": "", "material": "gamma0 = 1e-3"}
HARD = {"rho": "", "law": '[interaction]\nkind = "hard_wall"', "material": "e_star = 1.0"}


def _spec(tmp_path, name, law, extra=""):
    p = tmp_path / f"{name}.toml"
    p.write_text(JOB.format(**law, extra=extra))
    return p


def test_expansion_cuts_each_chain_deterministically(tmp_path):
    """5 pressures, L = 2: segments of 2, 2, 1 per chain; the later segments' tasks carry their start
    (``chain_start``) in their options, so each segment has its own chain key and is a unit of its own; the
    ids differ from the uncut job's (another computation) and are unique."""
    cut = T.expand(specmod.load(_spec(tmp_path, "cut", EXP, "split_chains = 2")))
    whole = T.expand(specmod.load(_spec(tmp_path, "whole", EXP)))
    assert len(cut) == len(whole) == 10 and len({t.task_id for t in cut}) == 10
    assert not {t.task_id for t in cut} & {t.task_id for t in whole}
    for seed in (3, 7):
        chain = [t for t in cut if t.seed == seed]
        assert [t.sigma0 for t in chain] == sorted((t.sigma0 for t in chain), reverse=True)
        starts = [t.opt("chain_start") for t in chain]
        s = [t.sigma0 for t in chain]
        assert starts == [None, None, s[2], s[2], s[4]]
        assert len({t.chain for t in chain}) == 3
    units = T.make_units(cut)
    assert sorted(len(u.tasks) for u in units) == [1, 1, 2, 2, 2, 2]
    assert {u.kind for u in units if len(u.tasks) == 2} == {"chain"}


@pytest.mark.parametrize("law", [EXP, HARD], ids=["exponential", "hard_wall"])
def test_cut_chain_results_within_the_solver_tolerance(tmp_path, law):
    """Every row of the cut job within tol (1e-6, relative mean gap) of the uncut job's at the same grid point;
    the first segment's rows (the same warm starts) bit for bit; the cold-started ones not all bit for bit (the
    cut did change their start)."""
    a, b = tmp_path / "whole.h5", tmp_path / "cut.h5"
    runner.run(_spec(tmp_path, "whole", law), a, progress="none", mpi="off")
    runner.run(_spec(tmp_path, "cut", law, "split_chains = 2"), b, progress="none", mpi="off")
    da, db = store.read(a), store.read(b)
    assert set(da.status) == set(db.status) == {"done"}
    m = da.merge(db, on=["hurst", "rho", "seed", "n", "sigma0"], suffixes=("_a", "_b"))
    m = m[m.method_a == "gfmd"]
    assert len(m) == 10
    rel = (m.mean_gap_a - m.mean_gap_b).abs() / m.mean_gap_a.abs()
    assert rel.max() < 1e-6
    area = (m.contact_area_a - m.contact_area_b).abs()
    assert area.max() < 1e-3  # a few pixels of 64 x 64 at most
    first = m.groupby("seed").sigma0.transform(lambda s: s >= sorted(s, reverse=True)[1])
    assert (m[first].mean_gap_a == m[first].mean_gap_b).all()
    assert (m[~first].mean_gap_a != m[~first].mean_gap_b).any()


@pytest.mark.parametrize(("law", "extra", "match"), [
    (EXP, "split_chains = 0", r"split_chains: expected an integer >= 1"),
    (EXP, "split_chains = 2\nwarm_start = false", "only with warm_start = true"),
    ({"rho": "rho = [2e-2]\n", "law": '[interaction]\nkind = "adhesive"\nwork = 1e-4', "material": "e_star = 1.0"},
     "split_chains = 2", "depends on the load path"),
    ({**HARD, "material": "e_star = 1.0\nhardness = 10.0"}, "split_chains = 2", "plastic flow depends on the load"),
])
def test_split_chains_refused(tmp_path, law, extra, match):
    with pytest.raises(SpecError, match=match):
        specmod.load(_spec(tmp_path, "bad", law, extra))
