"""Job specs shipped with the package (package data), so that ``gapsweep demo`` works from an installed wheel.

``jobs/demo.toml`` in the repository is a link to ``demo.toml`` here.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

__all__ = ["path"]


def path(name: str) -> Path:
    """Path of the shipped job spec ``name`` (e.g. ``"demo"`` or ``"demo.toml"``)."""
    fname = name if name.endswith(".toml") else f"{name}.toml"
    p = Path(str(resources.files(__name__) / fname))
    if not p.is_file():
        raise FileNotFoundError(f"no shipped job spec {fname!r} in gapsweep.jobs")
    return p
