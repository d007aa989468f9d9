"""Research scripts that made ``docs/results/`` (not part of the installed package; run from a checkout, e.g.
``python -m studies.predictors_heldout --set heldout --out docs/results``). They use the public API of gapsweep
and :mod:`gapsweep.analysis`; their outputs and the exact command lines are listed in docs/results/README.md."""


def track(code_paths: list[str]) -> None:
    """Record this study's provenance (benchmarks/_record.py, issue 40): at exit every file it wrote under its
    ``--out`` folder gets the project's commit, the command, the machine, the date, the library versions and
    ``code_paths`` (the code it measures), so scripts/check_docs.py can tell when the figures went stale."""
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "benchmarks" / "_record.py"
    spec = importlib.util.spec_from_file_location("_bench_record", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.track(code_paths)
