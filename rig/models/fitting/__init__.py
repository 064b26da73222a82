"""Fitting a model by maximum likelihood: the likelihood and its gradient, the optimiser, grouped nodes
for large data, the closed form of the power law, when to stop."""
