"""Docs that cannot drift: check the numbers quoted in README.md and the pages of docs/ (docs/benchmarks*.md,
docs/history.md and every other page; not docs/results/, which holds results) against the result files they name
(issue 29 item 5), and the provenance of those files (issue 40). Run by tests/test_docs.py (so by scripts/test.sh
and CI):

    python scripts/check_docs.py            # exit 0, or 1 with one line per problem
    python scripts/check_docs.py --debts    # also the unsourced sections and the results awaiting re-measurement

The convention (docs/benchmarks.md, "How numbers are checked"):

* A **checked number** is a Markdown link whose text starts with the number as quoted and whose target is a
  result file with a key after ``#``:  ``[0.27 s](benchmarks/results/gfmd_limit/new_h200.json#rows[n=16384].t_s)``.
  Paths are relative to the Markdown file. Keys:

  - JSON / CSV: a path of dict keys and list indices separated by dots; ``*`` takes every element of a list;
    ``[k=v]`` keeps the elements whose ``k`` reads ``v``; then operations after ``|``: ``min``, ``max``,
    ``median``, ``mean``, ``sum``, ``len``, ``abs``, ``*F``, ``/F`` (F a number), ``inv`` (1/x).
    A CSV file is a list of rows (dicts by column name), numbers converted.
  - any file read as text (.txt, .log, .md, also .json): ``re:REGEX`` whose first group is the number (write the
    target in ``<...>`` when the regex has spaces or parentheses; a literal ``|`` is ``\x7c``, since ``|`` starts
    an operation); ``re*:REGEX`` takes every match, for the ``|`` operations.

  The quoted number matches when the file's value rounds to it at the quoted precision (``0.27`` matches
  0.2651...0.2749...; ``38`` matches 37.5...38.49); ``~1e-10`` (a tilde) matches within half a decade; ``≤ x`` /
  ``< x`` (before the number, inside the link text) match any value up to x. Thousands separators are read.
* **Strict sections** (README's "At a glance", and any section of docs/benchmarks*.md with the line
  ``<!-- check: strict -->``): every number outside code spans must be a checked number. Parameters of a run
  (``N = 2048``, ``tol 1e-6``) are written as code.
* **Sourced sections** (every other ``##`` section of docs/benchmarks*.md that quotes numbers): name at least one
  result file (``benchmarks/results/...`` or ``docs/results/...``) that exists.
* Every ``benchmarks/results/...`` path a checked file mentions exists (a path written as a stem, e.g.
  ``contact_cpu_{a,b}`` or ``hardwall_*``, when some file starts with it).
* A section whose numbers come from a run whose raw output was not kept (or that only gives a command not run
  yet, naming the files it will write) says so with
  ``<!-- check: unsourced REASON -->``: it is listed as a debt (``--debts``), not a failure, and
  :data:`KNOWN_DEBTS` caps their number, so a new one fails the check until it is sourced or the cap is raised
  in review.
* **Provenance** (issue 40): every result file the checked docs cite (a checked number's file, a path they
  name, or every file a stem they name starts with) records the commit of this repository it was measured at
  and the code paths it measures (benchmarks/_record.py: a ``"provenance"`` key, a sidecar
  ``FILE.provenance.json`` or a ``# provenance:`` line). It fails the check when that commit is unknown to the
  repository, a code path did not exist at it, or the code paths differ between that commit and HEAD
  (``git diff COMMIT HEAD -- PATHS``): the number is stale, re-measure it or stop citing it. A cited file with
  no record is *unversioned* (measured before records existed). It may be cited

  - from ``docs/history.md`` (the dated record of figures not re-measured at the current code; also checked
    here, numbers against their files, but never judged stale), or
  - where a comment ``<!-- remeasure: PATH -->`` names it in the citing *scope* -- the table row, the list
    item, or the paragraph (lines between blank lines) -- and ``benchmarks/remeasure_cpu.sh`` or
    ``benchmarks/remeasure_gpu.sh`` writes PATH: a debt (listed by ``--debts``) until that script has run and
    PATH carries a record; a marker whose PATH then carries one fails (check the numbers, drop the marker), as
    does a marker naming a file that no remeasure script writes.

  Any other citation of an unversioned file fails. Without a git checkout (a source archive) this part is
  skipped with a warning; in a shallow clone a commit it lacks is a warning, not a failure.
"""

from __future__ import annotations

import csv
import functools
import json
import math
import re
import statistics
import sys
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
RECORD = ROOT / "benchmarks" / "_record.py"  # the provenance reader (this checkout's, whatever root is checked)
LINK = re.compile(r"\[([^\]]*)\]\((<[^>]*>|[^)\s]*)\)")
CODE = re.compile(r"`[^`]*`")
NUMBER = re.compile(r"(?<![\w.])([~≈]|[≤<]\s*)?(\d[\d,]*(?:\.\d+)?(?:[eE][-+]?\d+)?|\.\d+)")
RESULT_PATH = re.compile(r"(?:\.\./)?(?:benchmarks/results|docs/results)/[\w./-]+\w")
STRICT_MARK = "<!-- check: strict -->"
UNSOURCED = re.compile(r"<!-- check: unsourced (.*?)-->", re.S)
KNOWN_DEBTS = 7  # sections quoting numbers of runs whose raw output was not kept, or not run yet (issue 27)
DEBTS: list[str] = []
HISTORY = Path("docs") / "history.md"  # figures not re-measured at the current code: unversioned files allowed
REMEASURE = re.compile(r"<!-- remeasure: ([^\s>]+)[^>]*-->")
REMEASURE_SCRIPTS = (Path("benchmarks") / "remeasure_cpu.sh", Path("benchmarks") / "remeasure_gpu.sh")
# result file -> its citations: (where, the files named by remeasure markers in the citing scope, from history.md)
CITED: dict[Path, list[tuple[str, frozenset[str], bool]]] = {}
MARKERS: list[tuple[str, str]] = []  # (where, PATH) of every remeasure marker outside history.md
WARNINGS: list[str] = []


class CheckError(ValueError):
    pass


# --- reading a value from a result file --------------------------------------------------------------------------


def _num(x: Any) -> Any:
    if isinstance(x, str):
        try:
            return float(x.replace(",", ""))
        except ValueError:
            return x
    return x


def _load(path: Path) -> Any:
    if path.suffix == ".json":
        return json.loads(path.read_text(encoding="utf-8"))
    if path.suffix == ".csv":
        with open(path, newline="", encoding="utf-8") as f:
            return [{k: _num(v) for k, v in row.items()} for row in csv.DictReader(f)]
    return path.read_text(encoding="utf-8", errors="replace")


def _step(node: Any, part: str) -> Any:
    m = re.fullmatch(r"(\w*)\[(\w+)=([^\]]*)\]", part)
    if m:  # filter a list of dicts
        if m[1]:
            node = node[m[1]]
        keep = [x for x in node if isinstance(x, dict) and m[2] in x and _same(x[m[2]], m[3])]
        if not keep:
            raise CheckError(f"no element with {m[2]} = {m[3]}")
        return keep if len(keep) > 1 else keep[0]
    if part == "*":
        return list(node)
    if isinstance(node, list) and not re.fullmatch(r"-?\d+", part):  # a key of every element
        return [x[part] for x in node]
    if isinstance(node, list):
        return node[int(part)]
    if part not in node:
        raise CheckError(f"no key {part!r} (keys: {', '.join(map(str, list(node)[:12]))})")
    return node[part]


def _same(value: Any, text: str) -> bool:
    v = _num(value)
    if isinstance(v, (int, float)) and not isinstance(v, bool):
        try:
            return math.isclose(float(v), float(text), rel_tol=1e-12)
        except ValueError:
            return False
    return str(value) == text


def _split_path(path: str) -> list[str]:
    return [p for p in re.split(r"\.(?![^\[]*\])", path) if p]


def _apply(value: Any, op: str) -> Any:
    vals = value if isinstance(value, list) else None
    ops = {"min": min, "max": max, "median": statistics.median, "mean": statistics.fmean, "sum": sum, "len": len}
    if op in ops:
        if vals is None:
            raise CheckError(f"'{op}' needs a list")
        return ops[op]([_num(v) for v in vals] if op != "len" else vals)
    if op in ("abs", "inv") or op[:1] in "*/":
        f = {"abs": abs, "inv": lambda x: 1.0 / x}.get(op) or (
            (lambda x: x * float(op[1:])) if op[0] == "*" else (lambda x: x / float(op[1:])))
        return [f(_num(v)) for v in vals] if vals is not None else f(_num(value))
    raise CheckError(f"unknown operation {op!r}")


def value_of(path: Path, key: str) -> float:
    """The number ``key`` names in the result file ``path`` (see the module docstring)."""
    expr, *ops = key.split("|")
    data = path.read_text(encoding="utf-8", errors="replace") if expr.startswith("re") else _load(path)
    if expr.startswith(("re:", "re*:")):
        pat = expr.split(":", 1)[1]
        found = re.findall(pat, data, re.M)
        if not found:
            raise CheckError(f"no match of {pat!r}")
        node: Any = [_num(f if isinstance(f, str) else f[0]) for f in found]
        if expr.startswith("re:"):
            node = node[0]
    else:
        node = data
        for part in _split_path(expr):
            node = _step(node, part)
    for op in ops:
        node = _apply(node, op)
    node = _num(node)
    if not isinstance(node, (int, float)) or isinstance(node, bool):
        raise CheckError(f"not a number: {str(node)[:60]!r}")
    return float(node)


# --- comparing a quoted number -----------------------------------------------------------------------------------


def quoted(text: str) -> tuple[str, float, str]:
    """(kind, number, as written) of the first number in a link text; kind is '=', '~' or '<='."""
    m = NUMBER.search(text.replace("−", "-"))
    if not m:
        raise CheckError(f"no number in the link text {text!r}")
    lead = (m[1] or "").strip()
    kind = "~" if lead in ("~", "≈") else "<=" if lead[:1] in ("≤", "<") else "="
    written = m[2].replace(",", "")
    return kind, float(written), written


def matches(kind: str, q: float, written: str, v: float) -> bool:
    if kind == "<=":
        return v <= q * (1 + 1e-12)
    if kind == "~":
        return q > 0 and v > 0 and abs(math.log10(v / q)) <= 0.5
    mant = written.lower().split("e")[0]
    exp = int(written.lower().split("e")[1]) if "e" in written.lower() else 0
    decimals = len(mant.split(".")[1]) if "." in mant else 0
    half = 0.5 * 10.0 ** (exp - decimals)
    return abs(v - q) <= half * (1 + 1e-9) + 1e-300


# --- the files -----------------------------------------------------------------------------------------------------


def _sections(text: str) -> list[tuple[str, int, str]]:
    """(heading, first line number, body) of each ``## `` section (the text before the first one: heading '')."""
    out, head, start, buf = [], "", 1, []
    for i, line in enumerate(text.splitlines(), 1):
        if line.startswith("## "):
            out.append((head, start, "\n".join(buf)))
            head, start, buf = line[3:].strip(), i, []
        else:
            buf.append(line)
    out.append((head, start, "\n".join(buf)))
    return out


def _target(md: Path, dest: str) -> tuple[Path, str] | None:
    dest = dest[1:-1] if dest.startswith("<") else dest
    path, _, key = dest.partition("#")
    if not RESULT_PATH.search(path) or not key:
        return None
    return (md.parent / path).resolve(), key


ITEM = re.compile(r"\s*(?:[-*+]|\d+[.)])\s")  # a line that starts a list item


def _scope_marks(lines: list[str], i: int) -> frozenset[str]:
    """The files named by ``<!-- remeasure: PATH -->`` comments in the scope of line ``i``: its table row, its
    list item (the bullet's line and its continuation lines), or its paragraph (the lines between blank lines)."""
    def marks(line: str) -> list[str]:
        return REMEASURE.findall(CODE.sub("", line))

    def edge(line: str) -> bool:  # a line no scope crosses
        return not line.strip() or line.lstrip().startswith(("|", "#"))

    if lines[i].lstrip().startswith("|"):
        return frozenset(marks(lines[i]))
    lo = hi = i
    while lo > 0 and not ITEM.match(lines[lo]) and not edge(lines[lo - 1]):
        lo -= 1
    while hi + 1 < len(lines) and not edge(lines[hi + 1]) and not ITEM.match(lines[hi + 1]):
        hi += 1
    return frozenset(x for line in lines[lo:hi + 1] for x in marks(line))


def _cite(path: Path, md: Path, lines: list[str], i: int, line0: int, history: bool) -> None:
    CITED.setdefault(path.resolve(), []).append(
        (f"{md.relative_to(ROOT)}:{line0 + i}", _scope_marks(lines, i), history))


def check_links(md: Path, text: str, line0: int, history: bool = False) -> tuple[list[str], str]:
    """Check every checked number of ``text``; returns the problems and the text with checked links removed."""
    problems = []
    lines = text.splitlines() or [""]

    def one(m: re.Match) -> str:
        tgt = _target(md, m[2])
        if tgt is None:
            return m[1]  # an ordinary link: its text stays in
        i = text[: m.start()].count(chr(10))
        where = f"{md.relative_to(ROOT)}:{line0 + i}"
        path, key = tgt
        _cite(path, md, lines, i, line0, history)
        try:
            if not path.is_file():
                raise CheckError(f"no file {path.relative_to(ROOT) if path.is_relative_to(ROOT) else path}")
            kind, q, written = quoted(m[1])
            v = value_of(path, key)
            if not matches(kind, q, written, v):
                raise CheckError(f"quoted {m[1]!r} but {path.name}#{key} is {v:.6g}")
        except (CheckError, KeyError, IndexError, TypeError, ValueError, OSError) as e:
            problems.append(f"{where}: {e}")
        return ""

    return problems, LINK.sub(one, text)


def check_file(md: Path, strict_sections: tuple[str, ...] = (), sourced: bool = False,
               history: bool = False) -> list[str]:
    text = md.read_text(encoding="utf-8")
    problems: list[str] = []
    for head, line0, body in _sections(text):
        first = line0 + 1 if head else line0  # the line number of the body's first line
        errs, rest = check_links(md, body, first, history)
        if not history:
            for m in REMEASURE.finditer(CODE.sub("", body)):
                MARKERS.append((f"{md.relative_to(ROOT)}:{first + CODE.sub('', body)[: m.start()].count(chr(10))}",
                                m[1]))
        problems += errs
        plain = CODE.sub("", rest)
        plain = re.sub(r"<!--.*?-->", "", plain, flags=re.S)
        strict = head.startswith(strict_sections) if strict_sections else False
        bare = CODE.sub("", body)  # a marker quoted in a code span is no marker
        strict = strict or STRICT_MARK in bare
        if strict:
            for i, line in enumerate(plain.splitlines()):
                for m in NUMBER.finditer(line):
                    problems.append(f"{md.relative_to(ROOT)}:{first + i}: the number {m[2]!r} names no "
                                    f"result file (a checked link, or a parameter in code)")
        elif UNSOURCED.search(bare):
            DEBTS.append(f"{md.relative_to(ROOT)}:{line0}: {head}: {UNSOURCED.search(bare)[1].strip()}")
        elif sourced and head and NUMBER.search(CODE.sub("", body)) and not _names_result(md, body):
            problems.append(f"{md.relative_to(ROOT)}:{line0}: section {head!r} quotes numbers but names no "
                            "result file that exists")
        body_lines = body.splitlines() or [""]
        for pm in RESULT_PATH.finditer(body):
            p = pm[0]
            if UNSOURCED.search(bare):
                break  # a command not run yet names the files it will write
            if not _exists(md, p.rstrip(".,;:")):
                problems.append(f"{md.relative_to(ROOT)}:{line0}: names {p}, which does not exist")
            for base in (md.parent, ROOT):
                f = base / p.rstrip(".,;:")
                # a file, or a stem naming a family of files (``contact_cpu_{a,b}``, ``hardwall_*``): each cited
                family = [f] if f.is_file() else [x for x in f.parent.glob(glob_escape(f.name) + "*") if x.is_file()
                                                  and not x.name.endswith(".provenance.json")] \
                    if f.parent.is_dir() and not f.is_dir() else []
                for x in family:
                    _cite(x, md, body_lines, body[: pm.start()].count("\n"), first, history)
                if family:
                    break
    return problems


def _exists(md: Path, p: str) -> bool:
    for base in (md.parent, ROOT):
        f = base / p
        if f.exists() or (f.parent.is_dir() and any(f.parent.glob(glob_escape(f.name) + "*"))):
            return True
    return False


def glob_escape(name: str) -> str:
    return re.sub(r"([*?\[])", r"[\1]", name)


def _names_result(md: Path, body: str) -> bool:
    return any(_exists(md, p.rstrip(".,;:")) for p in RESULT_PATH.findall(body))


# --- provenance of the cited result files (issue 40) --------------------------------------------------------------


@functools.cache
def _record_module() -> Any:
    """benchmarks/_record.py of this checkout (its functions take the repository root as an argument), loaded
    once."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("_bench_record", RECORD)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _git_ok(root: Path, *args: str) -> str | None:
    """``git -C root ARGS``'s output or None: the provenance reader's own (benchmarks/_record.py), 60 s at most."""
    return _record_module()._git(root, *args, timeout=60)


def remeasured_paths(root: Path = ROOT) -> set[str]:
    """The result files (paths relative to the root) named in benchmarks/remeasure_{cpu,gpu}.sh, the scripts the
    lead runs after a code freeze to re-measure the cited legacy figures."""
    out: set[str] = set()
    for f in REMEASURE_SCRIPTS:
        if (root / f).is_file():
            out |= set(RESULT_PATH.findall((root / f).read_text(encoding="utf-8")))
    return out


def check_provenance(files: dict[Path, list[tuple[str, frozenset[str], bool]]] | set[Path] | list[Path],
                     root: Path = ROOT, markers: list[tuple[str, str]] | None = None) -> list[str]:
    """Problems of the cited result ``files`` (module docstring, "Provenance"): a mapping file -> its citations
    ``(where, files named by remeasure markers in scope, from history.md)``, or a plain collection (each cited
    once from a current page, unmarked); ``markers``: the ``(where, PATH)`` of the remeasure markers outside
    history.md. Warnings and debts go to WARNINGS."""
    rec_mod = _record_module()
    if rec_mod.project_commit(root) is None:
        WARNINGS.append(f"{root} is not a git checkout of the project: the results' provenance is not checked")
        return []
    shallow = _git_ok(root, "rev-parse", "--is-shallow-repository") == "true"
    cites = files if isinstance(files, dict) else {Path(x): [("(cited)", frozenset(), False)] for x in files}
    problems = []
    rescripts = " or ".join(str(x) for x in REMEASURE_SCRIPTS)
    planned = remeasured_paths(root)
    for where, path in markers or []:
        f = root / path
        if not f.is_file():
            problems.append(f"{where}: the remeasure marker names {path}, which does not exist")
        elif path not in planned:
            problems.append(f"{where}: the remeasure marker names {path}, which {rescripts} does not write")
        elif (rec_mod.read(f) or {}).get("commit"):
            problems.append(f"{where}: {path} has been re-measured (it carries a provenance record): check the "
                            "numbers of its lines against it and drop the remeasure marker")
    merged: dict[Path, list[tuple[str, frozenset[str], bool]]] = {}
    for x, c in cites.items():
        merged.setdefault(Path(x).resolve(), []).extend(c)
    for f in sorted(merged):
        if not f.is_file() or not f.is_relative_to(root.resolve()):
            continue
        rel = str(f.relative_to(root.resolve()))
        if rel.endswith(rec_mod.SIDECAR):  # records are no results
            continue
        current = sorted({(w, marks) for w, marks, hist in merged[f] if not hist})
        if not current:
            continue  # cited from docs/history.md only: a dated figure, never judged stale
        rec = rec_mod.read(f)
        if not rec or not rec.get("commit"):
            for w, marks in current:
                if rel in marks:
                    WARNINGS.append(f"awaiting re-measurement ({rescripts}): {rel} ({w})")
                else:
                    problems.append(f"{w}: cites {rel}, a result with no provenance record (measured before "
                                    "records existed): re-measure it with a benchmark that calls "
                                    "benchmarks/_record.py's track() (until then: its command in "
                                    f"{rescripts} and `<!-- remeasure: {rel} -->` beside the claim), or move the "
                                    f"claim to {HISTORY}")
            continue
        commit, paths = str(rec["commit"]), [str(x) for x in rec.get("code_paths") or []]
        if not paths:
            problems.append(f"{rel}: its provenance names no code paths (CODE_PATHS of its benchmark)")
            continue
        if _git_ok(root, "cat-file", "-e", f"{commit}^{{commit}}") is None:
            (WARNINGS if shallow else problems).append(
                f"{rel}: records commit {commit[:12]}, which this repository does not have"
                + (" (a shallow clone)" if shallow else ""))
            continue
        gone = [p for p in paths if _git_ok(root, "cat-file", "-e", f"{commit}:{p}") is None]
        if gone:
            problems.append(f"{rel}: its code path(s) {', '.join(gone)} did not exist at its commit {commit[:12]}: "
                            "the record names the wrong commit or the wrong code")
            continue
        # stale when the measured code differs between its commit and HEAD (a tree comparison: a result measured
        # on a branch merged since is judged by the code, not by the history's shape)
        if _git_ok(root, "diff", "--quiet", commit, "HEAD", "--", *paths) is None:
            last = _git_ok(root, "log", "-1", "--format=%h %cs", "HEAD", "--", *paths) or "?"
            problems.append(f"{rel}: stale: measured at {commit[:12]}, and {', '.join(paths)} changed since (last "
                            f"change {last}): re-measure it or stop citing it (its command: `{rec.get('command')}`, "
                            f"from {rec.get('cwd', '?')})")
    return problems


def check(root: Path = ROOT) -> list[str]:
    """Every problem of the checked docs (module docstring): README.md and every page of docs/ (not docs/results/,
    the results themselves, nor the generated API reference)."""
    DEBTS.clear()
    CITED.clear()
    WARNINGS.clear()
    MARKERS.clear()
    problems = check_file(root / "README.md", strict_sections=("At a glance",))
    for md in sorted((root / "docs").glob("benchmarks*.md")):
        problems += check_file(md, sourced=True)
    if (root / HISTORY).is_file():
        problems += check_file(root / HISTORY, sourced=True, history=True)
    for md in sorted((root / "docs").glob("*.md")):  # the other pages: their checked numbers and citations
        if not md.name.startswith("benchmarks") and md.resolve() != (root / HISTORY).resolve():
            problems += check_file(md)
    if len(DEBTS) > KNOWN_DEBTS:
        problems.append(f"{len(DEBTS)} unsourced sections, more than the {KNOWN_DEBTS} known: source the new one")
    problems += check_provenance(CITED, root, MARKERS)
    return problems


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    problems = check()
    for p in problems:
        print(p)
    if "--debts" in argv:
        for d in DEBTS:
            print(f"debt: {d}")
        for w in WARNINGS:
            print(f"warning: {w}")
    print(f"check_docs: {len(problems)} problem(s)" if problems else
          f"check_docs: every quoted number checked ({len(DEBTS)} unsourced section(s), {len(WARNINGS)} warning(s) "
          "-- legacy results awaiting re-measurement -- listed by --debts)")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
