"""The package's layout as a contract (docs/architecture.md, whose rooms table, rules and sweep order this file
reads): no import circle anywhere in gapsweep (imports inside functions count), every room imports only what its
row of the rooms table names, physics never imports the sweep, I/O or MPI, the sweep's core modules name no
method, the sweep reaches the physics through the doors rule 6 names, the farm is pure logic, analysis reads
stores only through gapsweep.store, library code prints nothing, the 0.1 names still import from
gapsweep/_compat/, and a new sweep method is one file."""

from __future__ import annotations

import ast
import importlib
import math
from pathlib import Path

import pytest

import gapsweep

PKG = Path(gapsweep.__file__).resolve().parent
PHYSICS = ("gapsweep.core", "gapsweep.surfaces", "gapsweep.gfmd", "gapsweep.theory", "gapsweep.gapdist",
           "gapsweep.flow", "gapsweep.reference")


def _module_name(path: Path) -> str:
    rel = path.relative_to(PKG.parent).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


COMPAT = PKG / "_compat"  # the 0.1 names' alias files (on gapsweep.__path__): not modules under their own path


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in PKG.rglob("*.py") if p.parent != COMPAT or p.name == "__init__.py"}


def _type_only(tree: ast.AST) -> set[int]:
    """ids of the import statements under ``if TYPE_CHECKING:`` (read by type checkers, never executed)."""
    out: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and ast.unparse(node.test) in ("TYPE_CHECKING", "typing.TYPE_CHECKING"):
            out |= {id(n) for b in node.body for n in ast.walk(b)}
    return out


def _imports(path: Path, name: str, known: set[str], *, runtime: bool = False) -> set[str]:
    """Every gapsweep module imported anywhere in the file (module level, functions, classes); ``runtime``: only
    the imports that execute (not those under ``if TYPE_CHECKING:``)."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    skip = _type_only(tree) if runtime else set()
    is_pkg = path.name == "__init__.py"
    out: set[str] = set()

    def add(mod: str) -> None:
        mod = gapsweep.STABLE_NAMES.get(mod, mod)
        if mod in known:
            out.add(mod)

    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.startswith("gapsweep"):
                    add(a.name)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                pkg = name.split(".") if is_pkg else name.split(".")[:-1]
                pkg = pkg[: len(pkg) - (node.level - 1)]
                base = ".".join(pkg + ([base] if base else []))
            if not base.startswith("gapsweep"):
                continue
            for a in node.names:
                sub = f"{base}.{a.name}"
                if gapsweep.STABLE_NAMES.get(sub, sub) in known:
                    add(sub)
                else:
                    add(base)
    out.discard(name)
    return out


def _graph(*, runtime: bool = False) -> dict[str, set[str]]:
    mods = _modules()
    known = set(mods)
    return {m: _imports(p, m, known, runtime=runtime) for m, p in mods.items()}


def _third_party(path: Path) -> set[str]:
    """Top-level names of the packages other than gapsweep that the file imports anywhere."""
    tree = ast.parse(path.read_text(encoding="utf-8"))
    names = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    names |= {(n.module or "").split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and not n.level}
    return names - {"gapsweep", ""}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []
    counter = [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_graph_sees_lazy_imports():
    """The graph builder finds imports inside functions (a circle hidden in a function is still a circle)."""
    g = _graph()
    assert "gapsweep.gfmd" in g["gapsweep.theory.improved"]  # imported inside hybrid()
    assert "gapsweep.sweep.schema" in g["gapsweep.sweep.store"]
    # and it would report a circle: a synthetic graph with one
    assert _cycles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": set()}) == [["a", "b", "c"]]


def test_no_import_cycle():
    """Rule 1, on the imports that execute: the package's ``if TYPE_CHECKING:`` names (the 0.1 names for type
    checkers) never run, and every module imports the package ``gapsweep`` first anyway."""
    g = _graph(runtime=True)
    assert len(g) > 50
    assert _cycles(g) == []


def test_physics_never_imports_the_sweep_or_drivers():
    g = _graph()
    bad = [(m, d) for m, deps in g.items() if m.startswith(PHYSICS)
           for d in deps if d.startswith(("gapsweep.sweep", "gapsweep.cli", "gapsweep.demo"))]
    assert bad == []
    # nor I/O or MPI packages (h5py, mpi4py): those belong to the sweep
    bad = sorted(m for m, p in _modules().items() if m.startswith(PHYSICS) and _third_party(p) & {"h5py", "mpi4py"})
    assert bad == []


SWEEP_CORE = ("spec", "tasks", "execute", "runner", "store", "storecheck", "merge", "dataset", "budget",
              "provenance", "api")
# imports of method plug-ins by the sweep's core that docs/architecture.md rule 3 names: re-exports of 0.1 names
CORE_METHOD_IMPORTS = {("tasks", "gfmd"), ("tasks", "sde"), ("provenance", "sde")}


def test_sweep_core_names_no_method():
    """The spec validator, the task expansion, the runner, the store and its validation, merge and the dataset
    view iterate the method registry: no registered method's name appears among their string constants, and
    they import no plug-in but methods/base.py beyond the re-exports rule 3 lists (issue 40: the rule said
    "names no method" while tasks and provenance imported the gfmd and sde plug-ins, and the test knew only
    four of the six methods)."""
    from gapsweep.sweep import methods

    names = set(methods.names())
    assert {"theory", "gfmd", "sde", "fokker_planck", "hybrid", "multiscale"} <= names
    g = _graph()
    imported = {(m, d.split(".")[3]) for m in SWEEP_CORE for d in g[f"gapsweep.sweep.{m}"]
                if d.startswith("gapsweep.sweep.methods.") and d.split(".")[3] != "base"}
    assert imported == CORE_METHOD_IMPORTS, imported ^ CORE_METHOD_IMPORTS
    for mod in SWEEP_CORE:
        tree = ast.parse((PKG / "sweep" / f"{mod}.py").read_text(encoding="utf-8"))
        docs = {id(n.body[0].value) for n in ast.walk(tree)
                if isinstance(n, (ast.Module, ast.FunctionDef, ast.ClassDef)) and n.body
                and isinstance(n.body[0], ast.Expr) and isinstance(n.body[0].value, ast.Constant)}
        found = {n.value for n in ast.walk(tree) if isinstance(n, ast.Constant) and isinstance(n.value, str)
                 and id(n) not in docs and n.value in names}
        assert not found, f"gapsweep.sweep.{mod} names the method(s) {sorted(found)}"


ALIASES = sorted(gapsweep.STABLE_NAMES)


@pytest.mark.parametrize("old", ALIASES)
def test_stable_names_import_the_same_module(old):
    """Each 0.1 name is an alias file in gapsweep/_compat/ whose import gives the module it now lives in, the
    same object; a deprecated one warns, naming the release it goes in, attributed to the importing line; a
    stable one is silent."""
    import sys
    import warnings

    assert (COMPAT / f"{old.rpartition('.')[2]}.py").is_file()
    sys.modules.pop(old, None)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        mod = sys.modules[__import__(old) and old]  # a plain import statement's frames
    assert mod is importlib.import_module(gapsweep.STABLE_NAMES[old])
    parent, _, child = old.rpartition(".")
    assert getattr(importlib.import_module(parent), child) is mod
    assert mod.__spec__.name == gapsweep.STABLE_NAMES[old]  # the real module keeps its own spec
    dep = [str(x.message) for x in w if issubclass(x.category, DeprecationWarning)]
    if old in gapsweep.DEPRECATED_NAMES:
        assert dep == [f"{old} is a deprecated 0.1 name and goes in gapsweep 0.4: import {gapsweep.STABLE_NAMES[old]}"]
        assert w[0].filename == __file__  # attributed to the importer, not to the import machinery
    else:
        assert dep == []
    # `from gapsweep import <name>` (the README's form) gives the same module
    sys.modules.pop(old, None)
    delattr(importlib.import_module(parent), child)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        ns: dict = {}
        exec(f"from {parent} import {child}", ns)
    assert ns[child] is mod


def test_the_package_face_is_its_layout():
    """The top of gapsweep holds the real layout (the package, its drivers, the public reference solutions and
    the subpackages); the 0.1 names live in gapsweep/_compat/, one alias file per entry of STABLE_NAMES and no
    other; the deprecated names are a subset of them; an alias file imported under its own path says so."""
    tops = {p.name for p in PKG.iterdir() if p.suffix == ".py"}
    assert tops == {"__init__.py", "__main__.py", "cli.py", "demo.py", "reference.py"}, tops
    subs = {p.name for p in PKG.iterdir() if p.is_dir() and (p / "__init__.py").is_file()}
    assert subs == {"_compat", "analysis", "core", "flow", "gapdist", "gfmd", "jobs", "surfaces", "sweep", "theory"}
    files = {p.stem for p in COMPAT.glob("*.py")} - {"__init__"}
    assert files == {n.rpartition(".")[2] for n in gapsweep.STABLE_NAMES}
    assert all(n.count(".") == 1 for n in gapsweep.STABLE_NAMES)
    assert gapsweep.DEPRECATED_NAMES <= set(gapsweep.STABLE_NAMES) and len(gapsweep.DEPRECATED_NAMES) == 13
    assert str(COMPAT) in gapsweep.__path__ and gapsweep.__path__[0] == str(PKG)  # the real modules come first
    with pytest.raises(ImportError, match=r"gapsweep\._compat\.tasks is not a 0\.1 name"):
        importlib.import_module("gapsweep._compat.tasks")


def test_the_docs_table_of_the_0_1_names_is_the_package_table():
    """docs/architecture.md's table "The 0.1 names" lists every name of STABLE_NAMES once, with its module, and
    says "deprecated" exactly for DEPRECATED_NAMES."""
    import re

    head = ARCH.index("| 0.1 name | module | status |")
    rows = ARCH[head:].split("\n\n")[0].splitlines()[2:]
    table: dict[str, str] = {}
    deprecated: set[str] = set()
    for row in rows:
        names_c, mods_c, status = (c.strip() for c in row.strip().strip("|").split("|"))
        names = [n if n.startswith("gapsweep.") else f"gapsweep.{n}" for n in re.findall(r"`([^`]+)`", names_c)]
        mods = re.findall(r"`([^`]+)`", mods_c)
        if len(mods) == 1 and mods[0].endswith(".*"):
            targets = [mods[0][:-1] + n.rpartition(".")[2] for n in names]
        else:
            base = mods[0].rpartition(".")[0]
            targets = [m if m.startswith("gapsweep.") else base + m for m in mods]
        assert len(targets) == len(names), row
        assert not set(names) & set(table), row
        table.update(zip(names, targets))
        if "deprecated" in status:
            deprecated |= set(names)
    assert table == gapsweep.STABLE_NAMES
    assert deprecated == gapsweep.DEPRECATED_NAMES


def test_reload_of_the_real_module_after_the_alias(monkeypatch):
    """``importlib.reload`` of the real module (or of the alias, the same object) executes it again."""
    import gapsweep.store
    from gapsweep.sweep import api

    assert gapsweep.store is api and api.__spec__.name == "gapsweep.sweep.api"
    monkeypatch.setattr(api, "read", None)  # the alias shares it
    assert gapsweep.store.read is None
    assert importlib.reload(gapsweep.store) is api and callable(api.read)


def test_python_m_of_an_alias_runs_the_real_module(tmp_path):
    """``python -m gapsweep.runner`` (a 0.1 name) runs ``gapsweep.sweep.runner`` as ``__main__``, as ``python -m
    gapsweep.sweep.runner`` does (a library module: it defines the farm and exits 0, no traceback)."""
    import subprocess
    import sys

    for name in ("gapsweep.runner", "gapsweep.sweep.runner"):
        r = subprocess.run([sys.executable, "-m", name], capture_output=True, text=True, timeout=120, cwd=tmp_path,
                           env=_env())
        assert r.returncode == 0 and r.stderr == "", (name, r.stderr[-2000:])


def _env() -> dict[str, str]:
    import os

    return {**os.environ, "PYTHONPATH": str(PKG.parent) + os.pathsep + os.environ.get("PYTHONPATH", "")}


def test_the_package_uses_no_deprecated_name():
    """Every module of gapsweep (aliases aside) imports with DeprecationWarning as an error: the library itself
    never goes through a deprecated 0.1 name."""
    import subprocess
    import sys

    gpu_only = ("__main__", "_sde_cuda", "_sde_kernels", "_cuda", "_warp_kernels")
    mods = [m for m in sorted(_modules()) if m.rpartition(".")[2] not in gpu_only]
    code = "import importlib, sys\nfor m in sys.argv[1:]:\n    importlib.import_module(m)\nprint('ok')"
    r = subprocess.run([sys.executable, "-W", "error::DeprecationWarning", "-c", code, *mods], capture_output=True,
                       text=True, timeout=300, env=_env())
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-3000:]


def test_stable_names_of_the_readme_and_docs():
    from gapsweep import fokker_planck, gfmd, sde, store, surface, theory

    assert callable(surface.self_affine) and callable(theory.mean_gap) and callable(gfmd.solve)
    assert callable(sde.gap_samples) and callable(fokker_planck.solve)
    for f in ("read", "read_histograms", "diff", "merge", "to_dataset", "open_fields", "status"):
        assert callable(getattr(store, f)), f


# Rooms (docs/architecture.md): who may import whom. analysis is a consumer on the sweep's side: it reads stores
# (gapsweep.store = sweep/api) and uses physics; neither physics nor the sweep imports it.
ROOMS = {
    "physics": (PHYSICS, ("gapsweep.sweep", "gapsweep.analysis", "gapsweep.cli", "gapsweep.demo")),
    "sweep": (("gapsweep.sweep",), ("gapsweep.analysis", "gapsweep.cli", "gapsweep.demo")),
    "analysis": (("gapsweep.analysis",), ("gapsweep.cli", "gapsweep.demo")),
}


@pytest.mark.parametrize("room", sorted(ROOMS))
def test_rooms(room):
    g = _graph()
    mine, forbidden = ROOMS[room]
    bad = [(m, d) for m, deps in g.items() if m.startswith(mine) for d in deps if d.startswith(forbidden)]
    assert bad == []
    assert any(m.startswith(mine) for m in g)


# ---------------------------------------------------------------------------------------------------------
# the rooms table of docs/architecture.md, read from the doc and checked against every import

ARCH = (PKG.parent / "docs" / "architecture.md").read_text(encoding="utf-8")
OUTSIDE_ROOMS = {"gapsweep", "gapsweep._compat"}  # the package's __init__ and the 0.1 names' alias files


def _strip_notes(text: str) -> str:
    import re

    return re.sub(r"\([^()]*(\([^()]*\)[^()]*)*\)", "", text)


def _token_prefixes(token: str) -> tuple[str, ...]:
    """Module prefixes a backticked word of the "may import" column stands for (the doc's vocabulary)."""
    if token == "physics":
        return PHYSICS
    if token == "gapsweep":
        return ("gapsweep",)  # the package itself (its version), not all of it
    if "/" in token:  # a path: sweep/filesurface.py
        return ("gapsweep." + token.removesuffix(".py").rstrip("/").replace("/", "."),)
    if token.startswith("gapsweep."):  # a 0.1 name: gapsweep.store
        return (gapsweep.STABLE_NAMES[token],)
    assert (PKG / token).is_dir() or (PKG / f"{token}.py").is_file(), f"unknown room {token!r} in the table"
    return (f"gapsweep.{token}",)


def _rooms_table() -> dict[tuple[str, ...], tuple[str, ...]]:
    """{module prefixes of a row: module prefixes it may import} from the table "The rooms and what each may
    import" (studies/ aside: it is not part of the package)."""
    import re

    head = ARCH.index("| room | what lives there | may import |")
    rows = ARCH[head:].split("\n\n")[0].splitlines()[2:]
    out = {}
    for row in rows:
        room, _, may = (c.strip() for c in row.strip().strip("|").split("|"))
        mods = tuple("gapsweep." + p.removesuffix(".py").rstrip("/").split("/", 1)[1].replace("/", ".")
                     for p in re.findall(r"`([^`]+)`", room) if p.startswith("gapsweep/"))
        if not mods:
            assert "studies/" in room, row
            continue
        out[mods] = tuple(x for t in re.findall(r"`([^`]+)`", _strip_notes(may)) for x in _token_prefixes(t))
    return out


def _under(mod: str, prefixes: tuple[str, ...]) -> bool:
    return any(mod == p or (p != "gapsweep" and mod.startswith(p + ".")) for p in prefixes)


def test_rooms_table_of_the_docs():
    """Rule 4 as the table says it: every module of gapsweep sits in one row of the rooms table (or is the
    package's __init__ or a 0.1 alias), and imports (anywhere, TYPE_CHECKING too) only its own room and the rooms
    named in its row's "may import" column (issue 41: gfmd and theory imported surfaces, the drivers analysis,
    unlisted)."""
    table = _rooms_table()
    assert len(table) == 11 and ("gapsweep.core",) in table and table[("gapsweep.core",)] == ()
    g = _graph()
    bad, homeless = [], []
    for m, deps in sorted(g.items()):
        rows = [(mods, may) for mods, may in table.items() if _under(m, mods)]
        if m in OUTSIDE_ROOMS:
            assert rows == [], m
            continue
        if len(rows) != 1:
            homeless.append(m)
            continue
        mods, may = rows[0]
        bad += [(m, d) for d in sorted(deps) if not _under(d, mods) and not _under(d, may)]
    assert homeless == [] and bad == [], (homeless, bad)
    # and the check can fail: a physics module importing the sweep breaks the table
    assert not _under("gapsweep.sweep.api", table[("gapsweep.gfmd",)])


def _rule(number: int) -> str:
    start = ARCH.index(f"\n{number}. **")
    return ARCH[start:].split(f"\n{number + 1}. **")[0].split("\n\n")[0]


def test_the_sweep_reaches_physics_through_its_doors():
    """Rule 6: the modules of the sweep that import physics beyond core are exactly the doors the rule names
    (each door does, no other module does)."""
    import re

    text = _strip_notes(_rule(6).split("**:", 1)[1].split("; any module", 1)[0])
    doors = {t.rstrip("/") for t in re.findall(r"`([^`]+)`", text)}
    assert {"methods", "context", "spec"} <= doors, doors
    core = ("gapsweep.core",)
    beyond = tuple(p for p in PHYSICS if p not in core)
    users = {m.split(".")[2] for m, deps in _graph().items() if m.startswith("gapsweep.sweep.")
             and any(_under(d, beyond) for d in deps)}
    assert users == doors, (sorted(users - doors), sorted(doors - users))


def test_the_farm_is_pure_logic():
    """Rule 7: sweep/farm.py imports only the standard library (no MPI, no GPU, no I/O packages, no gapsweep)."""
    import sys

    path = PKG / "sweep" / "farm.py"
    assert _third_party(path) <= set(sys.stdlib_module_names), _third_party(path)
    assert _graph()["gapsweep.sweep.farm"] == set()
    assert "sweep/farm.py` imports nothing but the standard library" in _rule(7)


def test_analysis_reads_stores_only_through_the_store_module():
    """Rule 4: analysis opens no HDF5 file itself (no h5py, no mpi4py) and reaches the sweep only through
    gapsweep.store / gapsweep.dataset and filesurface (the rooms table)."""
    bad = sorted(m for m, p in _modules().items() if m.startswith("gapsweep.analysis")
                 and _third_party(p) & {"h5py", "mpi4py"})
    assert bad == []
    sweep = {d for m, deps in _graph().items() if m.startswith("gapsweep.analysis") for d in deps
             if d.startswith("gapsweep.sweep")}
    assert sweep <= {"gapsweep.sweep.api", "gapsweep.sweep.dataset", "gapsweep.sweep.filesurface"}, sweep


def test_library_code_prints_nothing_and_logs_under_gapsweep():
    """Rule 8: no ``print`` call outside the drivers (cli, demo), and every logger the package creates is
    ``__name__`` or a "gapsweep..." name (the CLI's one handler sees them); no root logger."""
    prints, loggers = [], []
    for m, p in sorted(_modules().items()):
        tree = ast.parse(p.read_text(encoding="utf-8"))
        for n in ast.walk(tree):
            if not isinstance(n, ast.Call):
                continue
            if isinstance(n.func, ast.Name) and n.func.id == "print" and m not in ("gapsweep.cli", "gapsweep.demo"):
                prints.append(f"{m}:{n.lineno}")
            if isinstance(n.func, ast.Attribute) and n.func.attr == "getLogger":
                arg = n.args[0] if n.args else None
                ok = (isinstance(arg, ast.Name) and arg.id == "__name__") or (
                    isinstance(arg, ast.Constant) and isinstance(arg.value, str)
                    and (arg.value == "gapsweep" or arg.value.startswith("gapsweep.")))
                if not ok:
                    loggers.append(f"{m}:{n.lineno}")
    assert prints == [] and loggers == [], (prints, loggers)
    assert "print` call outside the drivers" in _rule(8)


def test_studies_use_current_names_and_nothing_imports_them():
    """The studies/ row: research scripts import gapsweep by its current names (no deprecated 0.1 name), and no
    module of gapsweep imports studies (it is not installed)."""
    root = PKG.parent / "studies"
    files = sorted(root.glob("*.py"))
    assert len(files) > 3
    used = set()
    for p in files:
        tree = ast.parse(p.read_text(encoding="utf-8"))
        for n in ast.walk(tree):
            if isinstance(n, ast.Import):
                used |= {a.name for a in n.names}
            elif isinstance(n, ast.ImportFrom) and (n.module or "").startswith("gapsweep"):
                used |= {n.module} | {f"{n.module}.{a.name}" for a in n.names}
    assert used & gapsweep.DEPRECATED_NAMES == set()
    assert [m for m, p in _modules().items() if "studies" in _third_party(p)] == []


def test_every_file_the_architecture_names_exists():
    """The structural statements of docs/architecture.md name files and folders (`sweep/farm.py`, `core/slab.py`,
    `gfmd/_lean.py`, `tests/test_farm.py`, the data-path drawing's modules, ...): each exists, relative to the
    repository, the package, the sweep or gfmd (a file moved or deleted takes its docs along)."""
    import re

    root = PKG.parent
    drawing = ARCH[ARCH.index("```\njob spec"):].split("```", 2)[1]
    names = set(re.findall(r"`([A-Za-z0-9_./-]+(?:\.py|\.md|\.toml|/))`", ARCH))
    names |= {n for n in re.findall(r"[A-Za-z0-9_/]+\.py", drawing)}
    assert {"sweep/farm.py", "core/slab.py", "sweep/api.py", "sweep/execute.py"} <= names, sorted(names)
    bases = (root, PKG, PKG / "sweep", PKG / "gfmd")
    missing = sorted(n for n in names if not any((b / n).exists() for b in bases))
    assert missing == [], missing


def _sweep_definitions() -> set[str]:
    """Names the sweep defines: module-level functions, classes and constants, and ``Class.member`` for methods,
    class fields and attributes set on ``self``."""
    out: set[str] = set()
    for p in (PKG / "sweep").rglob("*.py"):
        for node in ast.parse(p.read_text(encoding="utf-8")).body:
            if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
                out.add(node.name)
            targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(
                node, ast.AnnAssign) else []
            for t in targets:
                out |= {n.id for n in ast.walk(t) if isinstance(n, ast.Name)}
            if isinstance(node, ast.ClassDef):
                for n in ast.walk(node):
                    if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef)):
                        out.add(f"{node.name}.{n.name}")
                    elif isinstance(n, ast.AnnAssign) and isinstance(n.target, ast.Name):
                        out.add(f"{node.name}.{n.target.id}")
                    elif isinstance(n, ast.Attribute) and isinstance(n.value, ast.Name) and n.value.id == "self" \
                            and isinstance(n.ctx, ast.Store):
                        out.add(f"{node.name}.{n.attr}")
    return out


# the code names of docs/architecture.md's farm section: (as the doc writes it, as the code defines it)
FARM_NAMES = (("_coordinate", "_coordinate"), ("_work", "_work"), ("_serial", "_serial"), ("_Local", "_Local"),
              ("READY", "TAG_READY"), ("WORK", "TAG_WORK"), ("ROW", "TAG_ROW"), ("FAULT", "TAG_FAULT"),
              ("STOP", "TAG_STOP"), ("farm.Worker.state", "Worker.state"), ("Farm.dispatch", "Farm.dispatch"),
              ("Farm.left", "Farm.left"), ("Farm.no_gpu", "Farm.no_gpu"), ("Farm.stop", "Farm.stop"),
              ("Context.prefetch", "Context.prefetch"), ("gpus.rank_gpu", "rank_gpu"))


def test_the_farm_section_names_code_that_exists():
    """docs/architecture.md's farm section names the runner's and the farm's functions, tags and fields; each is
    written there and defined in the sweep (a renamed function takes its docs along)."""
    section = ARCH[ARCH.index("## The farm"):].split("\n## ", 1)[0]
    defined = _sweep_definitions()
    assert "Farm.dispatch" in defined and "Farm.nonexistent" not in defined
    missing_doc = [d for d, _ in FARM_NAMES if f"`{d}`" not in section]
    missing_code = [c for _, c in FARM_NAMES if c not in defined]
    assert missing_doc == [] and missing_code == [], (missing_doc, missing_code)


def test_one_law_per_file_and_one_method_per_file():
    """"Where a new thing goes": each file of gfmd/interactions/ (base aside) defines one Interaction subclass,
    listed in INTERACTIONS, and every law of INTERACTIONS has a file of its own; each file of sweep/methods/ (base
    aside) defines one registered Method or Extension plug-in, and every registered built-in has its own file."""
    from gapsweep.gfmd import interactions
    from gapsweep.sweep import methods
    from gapsweep.sweep.methods import base

    def own(mod, kind):
        return [c for c in vars(mod).values() if isinstance(c, type) and issubclass(c, kind) and c is not kind
                and c.__module__ == mod.__name__]

    laws = {}
    for p in sorted((PKG / "gfmd" / "interactions").glob("*.py")):
        if p.stem not in ("__init__", "base"):
            mod = importlib.import_module(f"gapsweep.gfmd.interactions.{p.stem}")
            found = own(mod, interactions.Interaction)
            assert len(found) == 1, (p.stem, found)
            laws[p.stem] = found[0]
    listed = {cls for cls, _ in interactions.INTERACTIONS.values()}
    assert set(laws.values()) == listed and len(laws) >= 4
    plugins = {}
    for p in sorted((PKG / "sweep" / "methods").glob("*.py")):
        if p.stem not in ("__init__", "base"):
            mod = importlib.import_module(f"gapsweep.sweep.methods.{p.stem}")
            found = own(mod, base.Method) + own(mod, base.Extension)
            assert len(found) == 1, (p.stem, found)
            plugins[p.stem] = found[0]
    registered = {type(m) for m in base._REGISTRY.values()} | {type(e) for e in base._EXTENSIONS.values()}
    registered = {c for c in registered if c.__module__.startswith("gapsweep.")}  # built-ins, not a test's toy
    assert set(plugins.values()) == registered, (set(plugins.values()) ^ registered)
    builtin = {m for m in methods.names() if type(methods.get(m)).__module__.startswith("gapsweep.")}
    assert builtin <= {c.name for c in plugins.values()}  # a test's toy method (tests/fakegpu.py) may be registered


def test_no_top_level_analysis_package():
    """Reports and aggregation are gapsweep.analysis; nothing but gapsweep is installed (pyproject.toml)."""
    import tomllib

    root = PKG.parent
    assert not (root / "analysis").exists()
    cfg = tomllib.loads((root / "pyproject.toml").read_text(encoding="utf-8"))
    assert cfg["tool"]["setuptools"]["packages"]["find"]["include"] == ["gapsweep*"]


# ---------------------------------------------------------------------------------------------------------
# a new method is one file


PLUGIN = '''
"""A toy sweep method for the test: the paper's closed form of the field theory, as a method of its own."""
from gapsweep import theory
from gapsweep.sweep import readers as rd
from gapsweep.sweep.methods.base import Method, grid_tasks, register
from gapsweep.sweep.schema import TaskResult


@register
class PaperOnly(Method):
    name = "paper_only"
    keys = ("scale",)
    columns = ("mean_gap",)
    variables = {"mean_gap": ("paper_only_mean_gap", "mean gap, paper form", {"units": "1"})}

    def validate(self, key, t, env):
        return {"scale": rd.number(f"{key}.scale", t.get("scale", 1.0), gt=0.0)}

    def expand(self, spec):
        yield from grid_tasks(spec, self.name, seeds=[0], with_hist=False)

    def run(self, t, ctx, prev):
        sp = t.surface_params()
        g = theory.mean_gap(t.sigma0, form="paper", hurst=t.hurst, h_rms=sp["rms_height"], rho=t.rho,
                            gamma0=t.opt("gamma0"), lambda_l=sp["lambda_l"], lambda_s=sp["lambda_s"])
        return TaskResult("done", "", {"mean_gap": t.opt("scale") * g}), None
'''

JOB = """
[job]
name = "plugin"
[grid]
hurst = 0.8
rho = [5e-3, 1e-2]
sigma0 = [1e-3, 1e-2]
[surface]
lambda_l = 0.25
lambda_s = 0.0625
rms_height = 0.01
[methods.theory]
forms = ["paper"]
[methods.paper_only]
scale = {scale}
"""


def test_a_new_method_is_one_file(tmp_path, monkeypatch):
    from gapsweep import runner, spec, store
    from gapsweep.sweep import methods
    from gapsweep.sweep.methods import base

    (tmp_path / "toy_method.py").write_text(PLUGIN)
    monkeypatch.syspath_prepend(str(tmp_path))
    importlib.import_module("toy_method")
    try:
        assert "paper_only" in methods.names()
        with pytest.raises(spec.SpecError, match=r"methods\.paper_only\.scale"):
            spec.loads(JOB.format(scale=-1))
        job = tmp_path / "job.toml"
        job.write_text(JOB.format(scale=1.0))
        runner.run(job, tmp_path / "s.h5", mpi="off", progress="none")
        df = store.read(tmp_path / "s.h5")
        assert sorted(set(df.method)) == ["paper_only", "theory"] and (df.status == "done").all()
        mine = df[df.method == "paper_only"].set_index(["rho", "sigma0"]).mean_gap
        ref = df[df.method == "theory"].set_index(["rho", "sigma0"]).mean_gap
        assert len(mine) == 4 and all(math.isclose(mine[k], ref[k], rel_tol=1e-15) for k in ref.index)
    finally:
        base._REGISTRY.pop("paper_only", None)
    assert "paper_only" not in methods.names()


def test_signal_handlers_install_before_heavy_imports():
    """`python -m gapsweep` installs its SIGINT/SIGTERM handlers (gapsweep.sweep.limits) before numpy, h5py or
    the solvers load, so a signal during start-up is handled (docs/reliability.md)."""
    import subprocess
    import sys

    code = "import sys, gapsweep.sweep.limits; print(sorted(m for m in ('numpy', 'h5py', 'numba') if m in sys.modules))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60).stdout.strip()
    assert out == "[]", out


def test_schema_and_readers_sit_at_the_bottom():
    """docs/architecture.md rule 5: schema imports nothing of gapsweep, readers nothing but schema."""
    g = _graph()
    assert g["gapsweep.sweep.schema"] == set()
    assert g["gapsweep.sweep.readers"] <= {"gapsweep.sweep.schema"}


def _sweep_layers() -> list[list[str]]:
    """The groups of docs/architecture.md's "Inside the sweep, bottom to top:" paragraph, in order."""
    import re

    text = (PKG.parent / "docs" / "architecture.md").read_text(encoding="utf-8")
    para = text[text.index("Inside the sweep, bottom to top"):].split("\n\n")[0]
    para = re.sub(r"\([^()]*(\([^()]*\)[^()]*)*\)", "", para)  # the notes in parentheses
    para = para.split(":", 1)[1]  # after "Inside the sweep, bottom to top:"
    return [[n.rstrip("/") for n in re.findall(r"`([a-z_]+/?)`", grp)] for grp in para.split("→")]


def test_sweep_import_order_of_the_docs():
    """The sweep's modules, bottom to top as docs/architecture.md lists them: every module of gapsweep/sweep is
    listed, and none imports a module of a later group (issue 40: the paragraph put limits above batching and
    execute, and slabs above fields and context, which import them; outputs was missing)."""
    layers = _sweep_layers()
    level = {m: i for i, grp in enumerate(layers) for m in grp}
    assert len(layers) > 10 and "schema" in layers[0] and "slurm" in layers[-1], layers
    mods = {p.stem if p.parent.name == "sweep" else "methods" for p in (PKG / "sweep").rglob("*.py")
            if p.name != "__init__.py" or p.parent.name == "methods"}
    assert mods - set(level) == set(), f"not in the paragraph: {sorted(mods - set(level))}"
    g = _graph()

    def lv(name: str) -> int | None:
        parts = name.split(".")
        return level.get(parts[2]) if len(parts) >= 3 and parts[1] == "sweep" else None

    up = sorted((m, d) for m, deps in g.items() for d in deps
                if lv(m) is not None and lv(d) is not None and lv(d) > lv(m))
    assert up == [], up
