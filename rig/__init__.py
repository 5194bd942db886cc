"""Hardware for IPMC experiments: DAC streaming over serial, camera capture and tip tracking.

The rig is built in its own issue; this package reserves the name so that
``hybrid`` and ``rig`` install together.
"""
