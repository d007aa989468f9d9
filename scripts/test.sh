#!/usr/bin/env bash
# Set up (idempotent) and run the test suite: lint, then pytest (MPI tests launch mpiexec themselves).
#   bash scripts/test.sh [pytest args...]
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. "${GAPSWEEP_VENV:-.venv}/bin/activate"   # the venv setup.sh made (CI: one per Python)
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
ruff check .
python scripts/check_docs.py                      # docs that cannot drift (also tests/test_docs.py)
if python -c "import sphinx" 2>/dev/null; then     # the API reference from the docstrings (~25 s)
  PYTHON=python bash scripts/build_api_docs.sh build/api  # the venv's python (PYTHON may name the base one); prints "[api-docs] FAILED: ..." and stops the run on error
else
  echo "[api-docs] skipped: sphinx is not installed (it comes with the dev extra)"
fi
python -m pytest -q -p no:cacheprovider "$@"
