#!/usr/bin/env bash
# Rewrite the fixture stores of tests/data/stores by running the commits that wrote each layout (README.md).
#   bash tests/data/stores/make_fixtures.sh [LAYOUT=COMMIT ...]     (from the repository root, venv active)
# The stores record the commit that wrote them (attribute git_commit); never rewrite an old layout's fixture with
# another commit's code: the point is what that code wrote.
set -euo pipefail
root=$(pwd)
job=$root/tests/data/stores/fixture.toml
pairs=("$@")
[ ${#pairs[@]} -gt 0 ] || pairs=(format1=a678e7c format2=449a5c7 format3a=ca6983b format3b=de98333 format3c=6bc25eb
                                 format3d=a6b475f format4=576c959 format5=HEAD)
for p in "${pairs[@]}"; do
  name=${p%%=*} commit=${p#*=}
  wt=$(mktemp -d /tmp/gapsweep-fixture-XXXX)
  git worktree add -q --detach "$wt" "$commit"
  rm -f "$root/tests/data/stores/$name.h5"
  (cd "$wt" && PYTHONPATH="$wt" python -m gapsweep run "$job" --store "$root/tests/data/stores/$name.h5" --mpi off \
     --progress none)
  git worktree remove --force "$wt"
  echo "$name: written by $(git rev-parse --short "$commit")"
done
