"""Job specs shipped with the package (package data), so that ``gapsweep demo``, ``gapsweep run fig2 --store
out.h5`` and ``gapsweep jobs`` work from an installed wheel (docs/jobs.md "Shipped jobs").

The figure jobs of the paper (``fig2``, ``fig3``, ``fig4_5``, ``fig6``, ``fig6_grms1`` and their ``_quick``
variants), the contact examples (``contact_file``, ``measured_map``, ``adhesion_quick``, with their height maps
under ``data/``), the body examples (``layer_quick``: an elastic layer; ``plastic_quick``: a pressure cap;
``plastic_quick_elastic``: its twin without the cap) and ``demo``. ``jobs/<name>.toml`` in the repository is a
link to the file here.
"""

from __future__ import annotations

import tomllib
from importlib import resources
from pathlib import Path

__all__ = ["NoSuchJob", "describe", "names", "path", "resolve"]


def _folder() -> Path:
    return Path(str(resources.files(__name__)))


def names() -> list[str]:
    """Names of the shipped job specs (file names without ``.toml``), sorted."""
    return sorted(p.stem for p in _folder().glob("*.toml"))


def path(name: str) -> Path:
    """Path of the shipped job spec ``name`` (e.g. ``"demo"`` or ``"demo.toml"``)."""
    fname = name if name.endswith(".toml") else f"{name}.toml"
    p = _folder() / fname
    if not p.is_file():
        raise FileNotFoundError(f"no shipped job spec {fname!r} in gapsweep.jobs (shipped: {', '.join(names())})")
    return p


class NoSuchJob(FileNotFoundError, ValueError):
    """A job argument that is neither a file nor a shipped job name (the CLI's exit code 2: a bad argument)."""


def resolve(job: str | Path) -> Path:
    """A job argument of the command line: an existing file is that file; otherwise a bare name (no folder, e.g.
    ``fig2`` or ``fig2.toml``) is the shipped spec of that name. Anything else raises :class:`NoSuchJob` (a
    :class:`FileNotFoundError` and a :class:`ValueError`) naming the shipped specs."""
    p = Path(job)
    if p.is_file():
        return p
    if p.parent == Path(".") and (p.suffix in ("", ".toml")) and (_folder() / f"{p.stem}.toml").is_file():
        return path(p.stem)
    raise NoSuchJob(f"job spec {str(job)!r}: no such file, nor a shipped job name "
                    f"(`gapsweep jobs` lists them: {', '.join(names())})")


def describe(name: str) -> str:
    """The ``[job] description`` of a shipped spec ('' when it has none)."""
    with open(path(name), "rb") as f:
        return str(tomllib.load(f).get("job", {}).get("description", ""))
