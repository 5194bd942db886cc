"""The five figures of the `hybrid diagnose` report, and the statistics behind them.

``residual_time.png``, ``loops.png``, ``spectrum.png``, ``correlation.png`` and
``segments.png`` (`FIGURES`): the held-out residuals of the baseline and of the
extended model (the one with the named effect), each figure showing both,
computed from ``Diagnosis.to_dict()`` and ``Diagnosis.heldout``. Each is written
atomically (`atomic_open`); `format_nmse` is the NMSE format the figures and
``report.md`` share.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ..core._simulation import as_factor
from ..util._atomic import atomic_open
from ..util._figures import pyplot
from . import residual_tests as rt

#: Lags of the correlation figure and of ``evidence`` (``_evidence._evidence``).
MAX_LAG = 50
#: Segments of the drift figure (``residual_tests.segment_errors``' default).
SEGMENTS = 8
DPI = 120

#: File names of the figures, in the order the report shows them.
FIGURES = ("residual_time.png", "loops.png", "spectrum.png", "correlation.png", "segments.png")

_MODELS = (("baseline", "baseline", "C0"), ("extended", "extended", "C3"))


def format_nmse(x) -> str:
    """NMSE: three significant digits in e-notation."""
    return "—" if x is None else f"{x:.2e}"


# --------------------------------------------------------------------------- #
# Statistics behind the figures
# --------------------------------------------------------------------------- #


def correlations(residual, drive, max_lag: int = MAX_LAG) -> dict:
    """ACF (lags 1..max_lag), CCF with the drive (−max_lag..max_lag) and the 99 % bound."""
    acf = rt.autocorrelation(residual, max_lag)
    lags, ccf = rt.cross_correlation(residual, drive, max_lag)
    return {
        "acf_lags": np.arange(1, len(acf)),
        "acf": acf[1:],
        "ccf_lags": lags,
        "ccf": ccf,
        "bound": rt.confidence_bound(len(residual)),
    }


def count_loop_levels(loop: dict) -> int:
    """Drive levels (bins of `rt.loops`) with both a rising and a falling mean."""
    return int(np.sum(np.isfinite(loop["rising"]) & np.isfinite(loop["falling"])))


def _x_axis(held: dict) -> tuple[np.ndarray, list[float]]:
    """Time axis for the held-out parts laid end to end, and the boundaries between recordings.

    One recording keeps its own time stamps; later recordings follow the previous
    one's last sample after one sample interval.
    """
    t = np.asarray(held["t"], float)
    which = np.asarray(held["recording"])
    x = t.copy()
    boundaries = []
    starts = np.flatnonzero(np.diff(which) != 0) + 1
    for start in starts:
        step = float(np.median(np.diff(t[max(start - 50, 0) : start]))) if start > 1 else 0.0
        x[start:] = t[start:] - t[start] + x[start - 1] + step
        boundaries.append(float(x[start] - 0.5 * step))
    return x, boundaries


# --------------------------------------------------------------------------- #
# Figures
# --------------------------------------------------------------------------- #


def save_figure(fig, path: Path, plt) -> None:
    """Save as PNG through a temporary file and a rename, like the text files."""
    fig.tight_layout()
    try:
        with atomic_open(path, "wb") as handle:
            fig.savefig(handle, dpi=DPI, format="png")
    finally:
        plt.close(fig)


def _gaps(x) -> np.ndarray:
    """Indices where the time axis jumps (between held-out blocks): lines break there."""
    if len(x) < 3:
        return np.array([], dtype=int)
    step = np.diff(x)
    return np.flatnonzero(step > 1.5 * np.median(step)) + 1


def _figure_residual_time(held, d, path, plt):
    x, boundaries = _x_axis(held)
    gaps = _gaps(x)

    def broken(y):  # NaN between held-out blocks so that no line bridges the training data
        return np.insert(np.asarray(y, float), gaps, np.nan)

    w = held["w"]
    fig, (top, bottom) = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    top.plot(broken(x), broken(w), "k", lw=1.0, label="measured w")
    for (key, label, colour), lw in zip(_MODELS, (1.8, 1.0)):  # baseline wider: visible where they coincide
        top.plot(
            broken(x),
            broken(held[key]),
            color=colour,
            lw=lw,
            alpha=0.85,
            label=f"{label} (held-out NMSE {format_nmse(d[key]['nmse'])})",
        )
        bottom.plot(
            broken(x), broken(w - held[key]), color=colour, lw=0.8 * lw, alpha=0.85, label=f"{label} residual"
        )
    bottom.axhline(0.0, color="0.5", lw=0.6)
    for ax in (top, bottom):
        for b in boundaries:
            ax.axvline(b, color="0.3", ls=":", lw=1.0)
    top.set(
        ylabel=f"w ({d['units']['w']})", title=f"Held-out part: measured and predicted (cause: {d['cause']})"
    )
    bottom.set(
        xlabel="time (s)" + (", recordings end to end (dotted: boundaries)" if boundaries else ""),
        ylabel=f"residual w − ŵ ({d['units']['w']})",
    )
    top.legend(loc="upper right", fontsize=8)
    bottom.legend(loc="upper right", fontsize=8)
    save_figure(fig, path, plt)


def _figure_loops(held, d, path, plt):
    v = np.asarray(held["v_in"], float)
    direction = rt.travel_direction(v)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5), sharex=True, sharey=True)
    for ax, (key, label, _) in zip(axes, _MODELS):
        e = held["w"] - held[key]
        loop = rt.loops(e, v)
        for sign, name, light, dark, marker in (
            (1.0, "rising", "tab:orange", "darkorange", "^"),
            (-1.0, "falling", "tab:blue", "navy", "v"),
        ):
            sel = direction == sign
            ax.scatter(v[sel], e[sel], s=4, color=light, alpha=0.2, linewidths=0)
            ax.plot(
                loop["centres"], loop[name], marker=marker, color=dark, lw=1.8, label=f"{name} drive (mean)"
            )
        ax.axhline(0.0, color="0.5", lw=0.6)
        if count_loop_levels(loop) == 0:
            ax.text(
                0.5,
                0.04,
                "no drive level is visited both rising and falling:\n"
                "loops cannot open with this drive (use a sine or chirp)",
                transform=ax.transAxes,
                ha="center",
                va="bottom",
                fontsize=8,
                color="0.3",
            )
        separation = "n/a" if count_loop_levels(loop) == 0 else f"{loop['separation']:.3g} {d['units']['w']}"
        ax.set(
            xlabel=f"drive v_in ({d['units']['v_in']})", title=f"{label}: rising − falling rms {separation}"
        )
        ax.legend(loc="best", fontsize=8)
    axes[0].set_ylabel(f"residual w − ŵ ({d['units']['w']})")
    fig.suptitle(
        "Residual against drive level, by direction of travel (open loops: hysteresis; "
        "bent ends: saturation)",
        fontsize=10,
    )
    save_figure(fig, path, plt)


def _figure_spectrum(held, d, rate, path, plt):
    fig, ax = plt.subplots(figsize=(9, 4.2))
    for (key, label, colour), lw in zip(_MODELS, (2.6, 1.2)):  # baseline wider: visible where they coincide
        f, psd = rt.spectrum(held["w"] - held[key], rate)
        ax.semilogy(f[1:], psd[1:], color=colour, lw=lw, label=f"{label} residual")
    ax.set(
        xlabel="frequency (Hz)",
        ylabel=f"PSD of residual ({as_factor(d['units']['w'])}²/Hz)",
        title="Welch spectrum of the held-out residual (a peak: an unmodelled resonance)",
    )
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    save_figure(fig, path, plt)


def _figure_correlation(held, d, path, plt):
    fig, (left, right) = plt.subplots(1, 2, figsize=(11, 4.2))
    bound = None
    for i, (key, label, colour) in enumerate(_MODELS):
        c = correlations(held["w"] - held[key], held["v_in"])
        bound = c["bound"]
        shift = 0.15 * (1 if i else -1)
        left.vlines(c["acf_lags"] + shift, 0.0, c["acf"], color=colour, lw=1.2)
        left.plot(c["acf_lags"] + shift, c["acf"], "o", ms=2.5, color=colour, label=f"{label} residual")
        right.vlines(c["ccf_lags"] + shift, 0.0, c["ccf"], color=colour, lw=1.2)
        right.plot(c["ccf_lags"] + shift, c["ccf"], "o", ms=2.5, color=colour, label=f"{label} residual")
    for ax in (left, right):
        ax.axhline(bound, color="k", ls="--", lw=1.0, label=f"±99 % bound ({bound:.3f})")
        ax.axhline(-bound, color="k", ls="--", lw=1.0)
        ax.axhline(0.0, color="0.5", lw=0.6)
        ax.legend(fontsize=8, loc="upper right")
    left.set(
        xlabel="lag (samples)",
        ylabel="autocorrelation ρ_εε(k)",
        title="Residual autocorrelation (white: inside the band)",
    )
    right.set(
        xlabel="lag k (samples; k > 0: the drive leads)",
        ylabel="cross-correlation ρ_εu(k)",
        title="Residual–drive cross-correlation (peak at k > 0: delay)",
    )
    save_figure(fig, path, plt)


def _figure_segments(held, d, path, plt):
    fig, ax = plt.subplots(figsize=(9, 4.2))
    idx = np.arange(SEGMENTS)
    width = 0.38
    for i, (key, label, colour) in enumerate(_MODELS):
        errors = rt.segment_errors(held["w"], held[key], SEGMENTS)
        ax.bar(idx + (i - 0.5) * width, errors, width, color=colour, label=f"{label}")
    ax.set_xticks(idx, [str(i + 1) for i in idx])
    ax.set(
        xlabel="consecutive segment of the held-out part (1 = earliest)",
        ylabel="segment MSE / mean(w²)",
        title="Error by segment of the held-out part (a trend over segments: drift)",
    )
    ax.legend(fontsize=8)
    save_figure(fig, path, plt)


def write_figures(diagnosis, data: dict, out_dir: Path) -> dict[str, Path]:
    plt = pyplot()
    # The figures pick a prediction by name ("baseline", "extended"): the signals as named arrays.
    held = {
        f.name: np.asarray(getattr(diagnosis.heldout, f.name)) for f in dataclasses.fields(diagnosis.heldout)
    }
    rate = float(data["evidence"].get("rate_hz") or 1.0)
    paths = {name: out_dir / name for name in FIGURES}
    _figure_residual_time(held, data, paths["residual_time.png"], plt)
    _figure_loops(held, data, paths["loops.png"], plt)
    _figure_spectrum(held, data, rate, paths["spectrum.png"], plt)
    _figure_correlation(held, data, paths["correlation.png"], plt)
    _figure_segments(held, data, paths["segments.png"], plt)
    return paths
