"""Accuracy against the stage's ground truth: each stop's depth against where the wall was (`stop_figures`), and
the bias modelled from them (`bias`): docs/models.md, "Accuracy"."""

from .bias import PARAMS, BiasFit, fit_bias, model_bias
from .stop_figures import StopAccuracy, stop_accuracy
from .summary import Accuracy, accuracy_json, accuracy_lines, accuracy_of, accuracy_words, bias_export

__all__ = ["PARAMS", "Accuracy", "BiasFit", "StopAccuracy", "accuracy_json", "accuracy_lines", "accuracy_of", "accuracy_words", "bias_export", "fit_bias",
           "model_bias", "stop_accuracy"]
