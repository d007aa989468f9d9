"""Sphinx configuration of gapsweep's API reference (built from the docstrings; docs/api/README.md).

    bash scripts/build_api_docs.sh            # -> build/api/index.html
"""

import os
import sys

sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..", "..")))

import gapsweep

project = "gapsweep"
release = version = gapsweep.__version__
extensions = ["sphinx.ext.autodoc", "sphinx.ext.napoleon"]
autodoc_default_options = {"members": True, "undoc-members": False, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
# optional packages the import of a documented module may reach for: mocked, so the build needs none of them
autodoc_mock_imports = ["cupy", "cupyx", "warp", "mpi4py", "pyfftw", "numba", "tqdm", "SurfaceTopography"]
napoleon_google_docstring = True
napoleon_numpy_docstring = True
html_theme = "alabaster"
exclude_patterns = ["_build"]
suppress_warnings = ["ref.python"]
