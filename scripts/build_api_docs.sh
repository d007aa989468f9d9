#!/usr/bin/env bash
# Build the API reference from the docstrings (Sphinx autodoc + napoleon; docs/api/) into build/api.
#   bash scripts/build_api_docs.sh [OUTDIR]
# Fails (exit 1, "[api-docs] FAILED") when Sphinx fails or a documented module cannot be imported; other
# docstring-format warnings are counted, not fatal.
set -uo pipefail
cd "$(dirname "$0")/.."
out=${1:-build/api}
log=$(mktemp)
PY=${PYTHON:-python}
if ! $PY -c "import sphinx" 2>/dev/null; then
  echo "[api-docs] FAILED: sphinx is not installed (pip install -c constraints.txt 'gapsweep[dev]')" >&2
  exit 1
fi
start=$(date +%s)
if ! $PY -m sphinx -b html -q -E docs/api "$out" 2>"$log"; then
  cat "$log" >&2
  echo "[api-docs] FAILED: sphinx-build exited non-zero (log above)" >&2
  exit 1
fi
if grep -E "failed to import|autodoc: failed|No module named" "$log" >&2; then
  echo "[api-docs] FAILED: a documented module did not import (lines above)" >&2
  exit 1
fi
echo "[api-docs] built $out/index.html in $(( $(date +%s) - start )) s ($(grep -c -E "WARNING|ERROR" "$log" || true) docstring warnings)"
rm -f "$log"
