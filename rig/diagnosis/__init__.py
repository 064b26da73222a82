"""Where a model fails and which physical effect is most likely missing.

`bins` pools measured and predicted sigma in bins; `scores` turns that into the headline error a
person can follow (and the held-out score); `residuals` shows where the model fails; `candidates`
ranks the effects not yet in the model; `verdict` decides what is missing; `text` prints it.
"""

from .bins import BinComparison, BinnedSigma, compare_bins, pooled_sigma, range_bins, sigma_by_range
from .candidates import Candidate, choose, rank_candidates
from .verdict import Diagnosis, base_mismatch, default_model, diagnose
from .scores import Headline, headline, held_out_nll
from .residuals import Residuals, residuals
from .text import render_text

__all__ = ["BinComparison", "BinnedSigma", "compare_bins", "pooled_sigma", "range_bins", "sigma_by_range", "Candidate",
           "choose", "rank_candidates", "Diagnosis", "base_mismatch", "default_model", "diagnose", "Headline", "headline",
           "held_out_nll", "Residuals", "residuals", "render_text"]
