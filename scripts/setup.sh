#!/usr/bin/env bash
# Set up gapsweep on a fresh Debian/Ubuntu machine (root) or a laptop (no root).
#
#   bash scripts/setup.sh            # creates .venv with everything (MPI + parallel HDF5 where root)
#   GAPSWEEP_EXTRAS=xarray bash scripts/setup.sh   # a leaner install: core + the named extras (no MPI build)
#
# Versions: every pip install here is constrained by constraints.txt, the one list of tested pins.
# With root and apt: Debian's Open MPI + parallel HDF5, the mpi4py wheel and h5py built against
# that HDF5 (see docs/running.md). Without root: pip-only (MPI from the mpich wheel, serial HDF5);
# the sweep then falls back to rank-0 writing (GAPSWEEP_NO_APT=1 forces this path). Idempotent: a second run
# only checks.
set -euo pipefail
cd "$(dirname "$0")/.."
VENV=${GAPSWEEP_VENV:-.venv}
export DEBIAN_FRONTEND=noninteractive
PY=${PYTHON:-python3}
EXTRAS=${GAPSWEEP_EXTRAS:-all,test,dev}
PIP_C=(-c constraints.txt)

want_mpi() { case ",$EXTRAS," in *,all,*|*,mpi,*) return 0 ;; *) return 1 ;; esac; }
have_root_apt() { [ -z "${GAPSWEEP_NO_APT:-}" ] && [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null; }

if want_mpi && have_root_apt && ! dpkg -s libhdf5-openmpi-dev openmpi-bin pkg-config >/dev/null 2>&1; then
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

if want_mpi && ! python -c 'import h5py, sys; sys.exit(0 if h5py.get_config().mpi else 1)' 2>/dev/null; then
  if have_root_apt; then
    echo "[setup] h5py against parallel HDF5 (about 3 minutes)"
    pip install -q "${PIP_C[@]}" numpy Cython pkgconfig "setuptools>=77" packaging mpi4py
    CC=mpicc HDF5_MPI=ON HDF5_DIR=/usr/lib/x86_64-linux-gnu/hdf5/openmpi \
      pip install -q "${PIP_C[@]}" --no-binary=h5py --no-build-isolation --no-cache-dir h5py
    python -c 'import h5py; assert h5py.get_config().mpi, "h5py built without MPI"'
  else
    echo "[setup] no root/apt: pip-only MPI (mpich wheel) and serial h5py"
    pip install -q "${PIP_C[@]}" mpi4py mpich h5py
  fi
fi

# Installed once per (extras, pyproject.toml, constraints.txt): the stamp says what the venv holds.
STAMP="$VENV/.gapsweep-installed"
WANT="$EXTRAS $(cat pyproject.toml constraints.txt | sha256sum | cut -c1-16)"
if [ "$(cat "$STAMP" 2>/dev/null)" != "$WANT" ] || ! python -c 'import gapsweep' 2>/dev/null; then
  echo "[setup] gapsweep[$EXTRAS] and its dependencies"
  pip install -q "${PIP_C[@]}" -e ".[$EXTRAS]"
  echo "$WANT" > "$STAMP"
fi
echo "[setup] done: $(python -c 'import gapsweep, h5py; print("gapsweep", gapsweep.__version__, "| h5py mpi:", h5py.get_config().mpi)')"
if [ "$(id -u)" = 0 ] || [ "$(nproc)" -lt 4 ]; then
  echo "[setup] for mpirun/mpiexec with Open MPI as root or with more ranks than cores, first:"
  echo "          export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1 OMPI_MCA_rmaps_base_oversubscribe=1"
fi
