"""Loaded by Python at start-up when tests/hooks is on PYTHONPATH (test processes only): installs the fault
injection of gapsweep_test_hooks when a GAPSWEEP_TEST_* variable asks for it, and nothing otherwise."""

import os

if any(k.startswith("GAPSWEEP_TEST_") and k != "GAPSWEEP_TEST_DELAY" for k in os.environ):
    import gapsweep_test_hooks

    gapsweep_test_hooks.install()
