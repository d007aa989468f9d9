#!/usr/bin/env python3
"""Share of the collected tests checked against an independent truth (issue 41): the tests marked
``validation`` (tests/validation/ and the marked tests elsewhere) against all collected tests.

    python scripts/validation_share.py [pytest args...]     # e.g. tests/ or -m "not slow"

Prints the number of collected tests, the number marked ``validation`` and their share, and the same without the
tests marked ``peers`` (they skip where the peer codes are not installed, as in CI)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def collected(*args: str) -> int:
    """Tests ``pytest --collect-only -q`` reports for ``args`` (0 when none is selected)."""
    out = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider", *args],
                         cwd=ROOT, capture_output=True, text=True)
    m = re.search(r"(\d+)(?:/(\d+))? tests? (?:collected|selected)", out.stdout)
    if m is None:
        if "no tests collected" in out.stdout or "deselected" in out.stdout:
            return 0
        sys.exit(f"validation_share: could not read pytest's count:\n{out.stdout[-2000:]}{out.stderr[-2000:]}")
    return int(m.group(1))


def main(argv: list[str]) -> int:
    total = collected(*argv)
    marked = collected("-m", "validation", *argv)
    own = collected("-m", "validation and not peers", *argv)
    print(f"collected:  {total}")
    print(f"validation: {marked}")
    print(f"share:      {marked / total:.1%}" if total else "share:      n/a (no tests)")
    if total:
        print(f"without peers: {own} ({own / total:.1%}; the peers' tests skip where the peer codes are missing)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
