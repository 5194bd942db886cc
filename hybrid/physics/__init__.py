"""Simulations of a physics: implementations of `hybrid.core`'s `AbstractSimulation`.

The paper's distributed RC network (Eqs 4–14) with its Table 1 strip, the
continuous-time reference that checks its discretisation (diffrax), a generic
stable linear system of order N (`LTI`, ``--physics lti:N``), and
`resolve_physics`, which turns a command line's ``--physics`` into a
simulation (``rc``, ``lti:N``, ``file.py:Class``, ``module:Class``).
"""
