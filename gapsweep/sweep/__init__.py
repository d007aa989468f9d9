"""The sweep: job spec -> tasks -> method plug-ins -> result records -> HDF5 store, with the MPI task farm,
Slurm shards and merge, and the xarray/netCDF views (docs/architecture.md).

Bottom to top: ``schema`` (records and the store's layout) and ``readers`` (typed spec values); ``fields``,
``filesurface``, ``context`` (per-rank state); ``methods`` (one plug-in per method); ``spec``, ``execute``,
``batching``, ``tasks``; ``limits``, ``provenance``, ``lease``, ``storecheck``, ``store``, ``merge``, ``budget``,
``gpus``; ``dataset`` and ``api`` (the public reading functions); ``runner`` (the farm). Physics is reached only
through the method plug-ins and ``context``.
"""
