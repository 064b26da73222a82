"""Checks of a camera before an experiment: the projector switch and the Depth Quality Tool's figures."""
