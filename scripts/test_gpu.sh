#!/usr/bin/env bash
# The GPU tests (pytest marker "gpu": tests/gpu/ and the marked tests elsewhere): CUDA paths against their CPU counterparts. Run on a machine
# with an NVIDIA GPU and cupy + warp-lang installed; without a GPU every test skips.
#   bash scripts/test_gpu.sh [pytest args...]
# Uses the active python (or $PYTHON); run from anywhere.
set -euo pipefail
cd "$(dirname "$0")/.."
export PYTHONPATH="$PWD${PYTHONPATH:+:$PYTHONPATH}"
"${PYTHON:-python3}" -m pytest -q -p no:cacheprovider -m gpu tests "$@"
