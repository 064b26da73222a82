"""Settings of rig's own processes: one BLAS thread, Python's collector."""
