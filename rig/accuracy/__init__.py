"""Accuracy against the stage's ground truth: each stop's depth against where the wall was (`stop_figures`), and
the bias modelled from them (`bias`): docs/models.md, "Accuracy"."""

from .bias import PARAMS, BiasFit, fit_bias, model_bias
from .bias_effects import BIAS_EFFECTS, BiasEffect, BiasEffectFileError, BiasParam, load_bias_effects
from .stop_figures import StopAccuracy, stop_accuracy
from .summary import Accuracy, accuracy_json, accuracy_lines, accuracy_of, accuracy_words, bias_export

__all__ = ["PARAMS", "BIAS_EFFECTS", "Accuracy", "BiasEffect", "BiasEffectFileError", "BiasFit", "BiasParam",
           "StopAccuracy", "accuracy_json", "accuracy_lines", "accuracy_of", "accuracy_words", "bias_export", "fit_bias",
           "load_bias_effects", "model_bias", "stop_accuracy"]
