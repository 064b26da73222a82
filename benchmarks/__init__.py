"""rig's performance, each figure against a baseline measured in the same run: `python -m benchmarks`.

The figures (issue 16, docs/performance.md): the streaming statistics and a whole capture against
`frame.sum()` and a numpy Welford update; the fake camera against one normal draw per pixel; `rig fit`,
`rig fit --model` and `rig diagnose` on a full-resolution sweep against a 60-line script that computes
the paper's likelihood on the same file; the fit against a per-sample scipy MLE over the raw samples
(the paper's method without subsampling) at a size that baseline can finish; the fit's time against
pixel-stops at four sizes; `rig import` against a plain Pillow decode of the same PNGs.

Modules: `data` makes the recordings and the PNG folder, `capture`, `fitting` and `importing` time the
figures, `baselines` holds the baselines, `figures` the table and its JSON.
"""
