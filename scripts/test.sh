#!/usr/bin/env bash
# Set up (idempotent) and run the test suite: lint, then pytest (MPI tests launch mpiexec themselves).
#   bash scripts/test.sh [pytest args...]
set -euo pipefail
cd "$(dirname "$0")/.."
bash scripts/setup.sh
. .venv/bin/activate
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1
ruff check .
python -m pytest -q -p no:cacheprovider "$@"
