"""The sweep's public reading and store functions: the stable face ``gapsweep.store`` of version 0.1.

Users' scripts and the report (``gapsweep.analysis``) read stores through these names only: :func:`read` (a pandas frame
of tasks and results), :func:`read_histograms`, :func:`read_pressure_histograms`, :func:`read_attrs`,
:func:`status`, :func:`diff`, :func:`to_dataset` / :func:`export_netcdf` (xarray and netCDF views),
:func:`open_fields` (kept GFMD fields), :func:`merge` (shards), and :class:`Store` for writing.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

from gapsweep.sweep import dataset
from gapsweep.sweep.dataset import export_netcdf, open_fields, to_dataset
from gapsweep.sweep.merge import CONFLICT_CHOICES, merge
from gapsweep.sweep.schema import (
    FLOAT_RESULTS,
    FORMAT,
    FORMAT_VERSION,
    INT_RESULTS,
    MESSAGE_LEN,
    NEW_IN_V2,
    PRESSURE_HIST,
    RESULT_DTYPE,
    RESULT_DTYPE_V1,
    RESULT_DTYPES,
    STATUS,
    STATUS_NAMES,
    TASK_DTYPE,
    VOLATILE,
    StoreError,
    StoreWriteError,
)
from gapsweep.sweep.store import (
    Store,
    empty_results,
    io_failed,
    open_read,
    read,
    read_attrs,
    read_histograms,
    read_pressure_histograms,
    result_row,
    status,
    task_rows,
    upgrade_results,
)
from gapsweep.sweep.store import diff as _exact_diff

__all__ = [
    "CONFLICT_CHOICES", "FLOAT_RESULTS", "FORMAT", "FORMAT_VERSION", "INT_RESULTS", "MESSAGE_LEN", "NEW_IN_V2",
    "PRESSURE_HIST",
    "RESULT_DTYPE", "RESULT_DTYPES", "RESULT_DTYPE_V1", "STATUS", "STATUS_NAMES", "TASK_DTYPE", "VOLATILE", "Store",
    "StoreError", "StoreWriteError", "diff", "empty_results", "export_netcdf", "io_failed", "merge", "open_fields",
    "open_read", "read", "read_attrs", "read_histograms", "read_pressure_histograms", "result_row", "status",
    "task_rows", "to_dataset", "upgrade_results",
]


def diff(a: str | Path, b: str | Path, *, rtol: float = 0.0, atol: float = 0.0,
         ignore: Sequence[str] = VOLATILE) -> list[str]:
    """Differences in content between two stores (empty list: equal). With ``rtol = atol = 0`` (default) bit
    for bit; otherwise float results and histograms may differ by ``atol + rtol |b|`` (e.g. a merge of shards that
    summed in another order), see :func:`gapsweep.sweep.dataset.diff`."""
    if rtol == 0 and atol == 0:
        return _exact_diff(a, b, ignore=ignore)
    return dataset.diff(a, b, rtol=rtol, atol=atol, ignore=ignore)
