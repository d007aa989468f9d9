"""Gap distributions by statistics in magnification (docs/model.md M5): the gap SDE with its CPU/warp and CUDA
engines (``sde``, ``_sde_kernels``, ``_sde_cuda``), the Fokker-Planck solver (``fokker_planck``) and the
calibration of the closure constant against GFMD (``calibrate``). Free of I/O, MPI and the sweep."""
