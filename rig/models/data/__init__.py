"""What the data are: per-pixel statistics as the models see them (`ModelData`), read from a
recording, their covariates, order statistics, checks of stops and frames, and the rounding of depth."""
