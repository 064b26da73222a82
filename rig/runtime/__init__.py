"""What every rig process loads first, kept light (no numpy, no models): the settings of its own processes (one BLAS
thread, Python's collector) and the one error every command catches that the models raise (`EffectFileError`),
so that a command that fails early has not loaded the models, their scipy and numba (0.9 s)."""
