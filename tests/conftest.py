"""Suite-wide fixtures."""

from __future__ import annotations

import logging

import pytest


@pytest.fixture(autouse=True)
def _gapsweep_logger_restored():
    """A test that runs ``cli.main`` in-process leaves the CLI's handler on the ``gapsweep`` logger: put the
    logger back as it was, so the next test sees the library's own logging (tests/test_manners.py)."""
    log = logging.getLogger("gapsweep")
    # A handler the CLI left in a module- or session-scoped fixture (set up before this fixture) writes to the
    # stream of that fixture's setup, and the CLI adds none while one exists: drop it, so that a command this test
    # runs in-process logs to this test's stderr.
    log.handlers[:] = [h for h in log.handlers if not getattr(h, "_gapsweep_cli", False)]
    handlers, level, propagate = list(log.handlers), log.level, log.propagate
    yield
    log.handlers[:] = handlers
    log.setLevel(level)
    log.propagate = propagate
