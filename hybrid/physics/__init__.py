"""Simulations of a physics: implementations of `hybrid.core`'s `AbstractSimulation`.

The paper's distributed RC network (Eqs 4–14) with its Table 1 strip, and the
continuous-time reference that checks its discretisation (diffrax).
"""
