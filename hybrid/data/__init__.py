"""Measured and generated data: `Recording` (a drive and a displacement on one
time grid, with its checks, loaders and splits; `hybrid.load_mapped` reads a
lab's own file by mapping its columns) and the paper's drives (PRBS, sine,
chirp, pulse). Depends only on `hybrid.util`.
"""
