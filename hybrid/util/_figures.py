"""Figures like the paper's: Fig 3 (V_i, V_o, w normalised) and Figs 10–13 (target, Normal, Hybrid)."""

from __future__ import annotations

import numpy as np

from ._atomic import atomic_open


def save_png(fig, path, dpi: int = 120) -> None:
    """Save `fig` as a PNG at `path` atomically (a temporary file, then a rename) and close it."""
    import matplotlib.pyplot as plt

    try:
        with atomic_open(path, "wb") as handle:
            fig.savefig(handle, dpi=dpi, format="png")
    finally:
        plt.close(fig)


def pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _normalised(x):
    x = np.asarray(x, float)
    return x / np.max(np.abs(x))


def plot_mediatory_figure(recording, model, path, seconds: float = 60.0):
    """Fig 3: V_i, the computed V_o and w, each divided by its max |·|, with correlations to w."""
    plt = pyplot()
    v_o = np.asarray(model.mediatory(recording.v_in, recording.dt))
    n = min(len(recording), int(seconds * recording.rate))
    t = recording.t[:n]
    r_in = np.corrcoef(recording.v_in, recording.w)[0, 1]
    r_out = np.corrcoef(v_o, recording.w)[0, 1]
    fig, ax = plt.subplots(figsize=(9, 3.6))
    ax.plot(t, _normalised(recording.v_in)[:n], lw=1, label=f"$V_i$ (corr. with w: {r_in:.3f})")
    ax.plot(t, _normalised(v_o)[:n], lw=1.5, label=f"$V_o$ (corr. with w: {r_out:.3f})")
    ax.plot(t, _normalised(recording.w)[:n], "k--", lw=1, label="w")
    ax.set(
        xlabel="time (s)",
        ylabel="normalised",
        title="Drive $V_i$, computed $V_o$ (fitted hybrid model) and w, each by its max |·| (cf. Fig. 3)",
    )
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    save_png(fig, path)


def plot_fit_figure(recording, results, row: str, path, seconds: float = 90.0):
    """Figs 10–13: target and the Normal and Hybrid predictions on the test split."""
    plt = pyplot()
    split = recording.split()
    test = split.slices["test"]
    start = test.start
    n = min(test.stop - start, int(seconds * recording.rate))
    t = recording.t[start : start + n]
    fig, ax = plt.subplots(figsize=(9, 3.6))
    ax.plot(t, recording.w[start : start + n], "k", lw=1.5, label="Target")
    for kind, style in (("normal", "C1"), ("hybrid", "C0--")):
        model = results[kind].model
        w_hat = np.asarray(model.predict(recording.v_in, recording.dt, ((test.start, test.stop),)))[:n]
        nmse = results[kind].metrics["test"]["nmse"]
        ax.plot(t, w_hat, style, lw=1.2, label=f"{kind.capitalize()} (NMSE {nmse:.2e})")
    ax.set(
        xlabel="time (s)",
        ylabel="tip displacement w (mm)",
        title=f"{row} drive, test split: target, Normal and Hybrid models",
    )
    ax.legend(loc="upper right", fontsize=8)
    fig.tight_layout()
    save_png(fig, path)
