"""Command-line interface (thin): ``gapsweep demo``. The sweep commands join here (run, plan, status, merge)."""

from __future__ import annotations

import argparse
import sys


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="gapsweep", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    demo = sub.add_parser("demo", help="run the built-in default job (field theory of the paper's figure 2)")
    demo.add_argument("--out", default="out", help="output directory (default: out)")
    args = parser.parse_args(argv)
    if args.command == "demo":
        from gapsweep.demo import fig2_theory

        print(fig2_theory(args.out))
        print(f"figure: {args.out}/fig2_theory.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
