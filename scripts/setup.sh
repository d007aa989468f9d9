#!/usr/bin/env bash
# Set up gapsweep on a fresh Debian/Ubuntu machine (root) or a laptop (no root).
#
#   bash scripts/setup.sh            # creates .venv with everything (MPI + parallel HDF5 where root)
#
# With root and apt: Debian's Open MPI + parallel HDF5, the mpi4py wheel and h5py built against
# that HDF5 (see docs/running.md). Without root: pip-only (MPI from the mpich wheel, serial HDF5);
# the sweep then falls back to rank-0 writing (GAPSWEEP_NO_APT=1 forces this path). Idempotent: a second run
# only checks.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${GAPSWEEP_VENV:-.venv}
export DEBIAN_FRONTEND=noninteractive
PY=${PYTHON:-python3}

have_root_apt() { [ -z "${GAPSWEEP_NO_APT:-}" ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; }

if have_root_apt && ! dpkg -s libhdf5-openmpi-dev openmpi-bin pkg-config >/dev/null 2>&1; then
  echo "[setup] apt: Open MPI + parallel HDF5"
  apt-get update -q
  apt-get install -y -q --no-install-recommends libhdf5-openmpi-dev openmpi-bin pkg-config gcc g++ >/dev/null
fi

if [ ! -x "$VENV/bin/python" ]; then
  echo "[setup] venv $VENV"
  "$PY" -m venv "$VENV"
  "$VENV/bin/python" -m pip install -q -U pip
fi
. "$VENV/bin/activate"

if ! python -c 'import h5py, sys; sys.exit(0 if h5py.get_config().mpi else 1)' 2>/dev/null; then
  if have_root_apt; then
    echo "[setup] h5py against parallel HDF5 (about 3 minutes)"
    pip install -q numpy Cython pkgconfig "setuptools>=77" packaging mpi4py==4.1.2
    CC=mpicc HDF5_MPI=ON HDF5_DIR=/usr/lib/x86_64-linux-gnu/hdf5/openmpi \
      pip install -q --no-binary=h5py --no-build-isolation --no-cache-dir h5py==3.16.0
    python -c 'import h5py; assert h5py.get_config().mpi, "h5py built without MPI"'
  else
    echo "[setup] no root/apt: pip-only MPI (mpich wheel) and serial h5py"
    pip install -q mpi4py mpich h5py
  fi
fi

if ! python -c 'import gapsweep, warp, pyfftw, mpmath, pytest, ruff' 2>/dev/null; then
  echo "[setup] gapsweep and its dependencies"
  pip install -q -e ".[mpi,test,dev]"
fi
echo "[setup] done: $(python -c 'import gapsweep, h5py; print("gapsweep", gapsweep.__version__, "| h5py mpi:", h5py.get_config().mpi)')"
