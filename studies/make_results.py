"""Build ``docs/results/`` from the stores of the full jobs: figures (PNG + PDF), aggregated CSV tables,
the report (Markdown + HTML) and ``verdicts.md`` with the verdict on each claim of docs/model.md M6.

Usage (after running the full jobs, e.g. on the GPU machine)::

    gapsweep run jobs/fig2.toml   --store out/fig2.h5
    gapsweep run jobs/fig3.toml   --store out/fig3.h5
    gapsweep run jobs/fig4_5.toml --store out/fig4_5.h5
    gapsweep run jobs/fig6.toml   --store out/fig6.h5
    python -m studies.make_results out/fig2.h5 out/fig3.h5 out/fig4_5.h5 out/fig6.h5 --out docs/results

Only aggregated data is written (no raw fields): the CSV tables are a few hundred kB at most.
"""

from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from gapsweep.analysis import report

logger = logging.getLogger("gapsweep.analysis.make_results")

DEFAULT_STORES = ("out/fig2.h5", "out/fig3.h5", "out/fig4_5.h5", "out/fig6.h5")


def _write_pressure_trend(out: Path) -> None:
    """``pressure_trend.csv``: the M6 pressure trend per surface family (job), from ``theory_vs_gfmd.csv``."""
    import pandas as pd

    from gapsweep.analysis import compare

    if not (out / "theory_vs_gfmd.csv").is_file():  # contact-only stores: no field theory, no trend (no empty CSV)
        return
    trend = compare.pressure_trend(pd.read_csv(out / "theory_vs_gfmd.csv"))
    if len(trend):
        trend.to_csv(out / "pressure_trend.csv", index=False)


def main(argv: list[str] | None = None) -> int:
    """Command line: stores (default: the four full-job stores under out/) and ``--out`` (default docs/results)."""
    p = argparse.ArgumentParser(prog="python -m studies.make_results", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("stores", nargs="*", default=list(DEFAULT_STORES), help="store files (HDF5) of the full jobs")
    p.add_argument("--out", default="docs/results", help="output directory (default: docs/results)")
    p.add_argument("--allow-missing", action="store_true",
                   help="build from the stores that exist (claims without data say 'not enough data')")
    args = p.parse_args(argv)
    if not logging.getLogger().handlers:
        logging.basicConfig(format="%(message)s")
    logger.setLevel(logging.INFO)
    stores = [Path(s) for s in args.stores]
    missing = [str(s) for s in stores if not s.is_file()]
    if missing and not args.allow_missing:
        logger.error("make_results: missing store(s): %s (use --allow-missing to go on)", ", ".join(missing))
        return 1
    stores = [s for s in stores if s.is_file()]
    if not stores:
        logger.error("make_results: no store to read")
        return 1
    path = report.main(stores, args.out)
    _write_pressure_trend(Path(args.out))
    logger.info("report: %s", path)
    if (Path(args.out) / "verdicts.md").is_file():
        logger.info("%s", (Path(args.out) / "verdicts.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
