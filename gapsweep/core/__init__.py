"""Shared numerical ground of the physics: input checks (``checks``), optional extras (``extras``) and the FFT
backends (``fft``). Imports nothing else of gapsweep."""
