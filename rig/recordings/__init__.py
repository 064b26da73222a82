"""Fits of several recordings as plain data, their differences and their run-to-run scatter."""
