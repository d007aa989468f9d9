"""Totals of the fault-injection suite for docs/reliability.md, from a pytest JUnit XML report:

    python -m pytest tests/faults --junitxml=faults.xml
    python tests/faults/tally.py faults.xml            # totals and the per-case table (Markdown)

A case is one test (one parametrization). Cases of ``test_bad_inputs.py`` are bad inputs; every other case
injects one fault (or one fault per listed step). "handled" / "survived" means the test passed: every assertion
about the exit status, the message, the rows kept and the resumed store held.
"""

from __future__ import annotations

import sys
import xml.etree.ElementTree as ET
from collections import Counter


def main(path: str) -> None:
    root = ET.parse(path).getroot()
    rows = []
    for tc in root.iter("testcase"):
        cls, name = tc.get("classname", ""), tc.get("name", "")
        module = cls.rsplit(".", 1)[-1]
        if tc.find("skipped") is not None:
            outcome = "skipped"
        elif tc.find("failure") is not None or tc.find("error") is not None:
            outcome = "FAILED"
        else:
            outcome = "passed"
        kind = "bad input" if module == "test_bad_inputs" else "fault"
        rows.append((kind, module, name, outcome, float(tc.get("time", 0))))
    tot = Counter((k, o) for k, _, _, o, _ in rows)
    for kind, what in (("bad input", "handled cleanly"), ("fault", "survived, nothing lost")):
        n = sum(v for (k, _), v in tot.items() if k == kind)
        print(f"- {kind}s: {n} tried, {tot[(kind, 'passed')]} {what}, {tot[(kind, 'FAILED')]} failed, "
              f"{tot[(kind, 'skipped')]} skipped")
    print(f"- wall time of the cases: {sum(r[4] for r in rows):.0f} s\n")
    print("| kind | file | case | outcome |")
    print("|---|---|---|---|")
    for kind, module, name, outcome, _ in rows:
        print(f"| {kind} | {module}.py | `{name}` | {outcome} |")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "faults.xml")
