"""What a simulation gets wrong, and why: effects, `diagnose` and its report.

Physical effects that extend any simulation (`EffectStack`), the screened
search that fits each of them, the held-out evidence and decision, residual
tests, and the report. Works with any `AbstractSimulation`; it never imports
a particular physics.
"""
