"""Plumbing every room uses, knowing nothing of models or physics.

One error type for bad input (`InputError`), atomic file writes, checks that an
output path never overwrites an input, the watchdog that turns a stalled command
into an exit, the command line's bounds, and figure saving.
"""
