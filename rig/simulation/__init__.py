"""Simulated experiments, for the demo and for testing the diagnosis blind: hidden-effect scenarios,
the blind test (`rig validate-diagnosis`), the paper's window table (`rig paper-windows`) and `rig demo`."""
