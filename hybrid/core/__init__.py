"""The generic framework: a model is a simulation followed by a readout.

The simulation interface (`AbstractSimulation`: named, constrained parameters
with units, plausible and typical ranges, parameters frozen by default), the
readouts (linear, windowed D-MLP), the least-squares problem with its
structured Jacobian, Levenberg–Marquardt, `fit`, `fit_batch`, metrics and
serialisation. Nothing here knows a particular physics.
"""
