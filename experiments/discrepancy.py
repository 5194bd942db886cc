"""Hidden effect × seed → what `diagnose` names: the confusion table, the gains, the time.

    python experiments/discrepancy.py [--effects none,delay,back_relaxation+saturation,dead_zone,...]
                                      [--seeds 10 | --seed-list 2,3,7] [--duration 120]
                                      [--rate 30] [--drive prbs-multilevel] [--noise 0.01]
                                      [--search-effects delay,back_relaxation,...] [--virtual] [--dry-run]
                                      [--out experiments/results/discrepancy.json]

Each draw: a strip and an effect from the issue's ranges (`hybrid.ipmc._synthetic`:
ξρ/ξh 1–100, α 0.1–0.9, C_clamp 1 mF–1 F, gain 0.3–5 mm/V; the effect made by
code separate from the extensions that find it), a recording of the drive with
camera exposure and noise, then `diagnose` on it. Prints one line per draw, then
the confusion table (true effect × named cause) and the held-out gains, over all
draws and over the identifiable ones (see `IDENTIFIABLE`), and writes every
candidate's held-out gain, ΔBIC, Ljung–Box Q and reasons to the JSON file (a later
step's candidates too: gain, eligibility, reasons), and both tables to the .md file beside it.

`--effects` takes the library's hidden effects, effects outside the library
(`hybrid.ipmc._outside_effects`: electrostatic, dead_zone, rate_dependent,
self_heating) and several at once joined by ``+`` (``back_relaxation+saturation``:
`hybrid.ipmc._hidden_pairs`). Beside the single-effect table, the summary has
the open-world tables: pairs (both named, one named, wrong names, none; and what a
search told the hidden effects names, `told_row`: what the recording carries), effects
outside the library (flagged unexplained, forced into a known name, nothing
said), false discoveries and false "unexplained" on effect-free draws, false
all-clears (an effect hidden, nothing named, nothing unexplained, while the
baseline leaves more than 2× the noise held out), and the noise floor `diagnose`
estimated against the noise the generator added. `--dry-run` makes the
recordings and prints their truth without running `diagnose`.

`--drive` takes one of the drives of `hybrid.make_drive`, or `prbs-multilevel`
(random levels in ±A held 0.5–10 s: steps for a delay and a mode, holds for a
relaxation, many levels reached from above and below for saturation and
hysteresis). `--virtual` also runs `diagnose` on recordings of the richer virtual
IPMC (`hybrid.virtual_recording`), whose extra physics is a real discrepancy.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

import jax
import numpy as np


def _drive(name: str, duration: float, rate: float, seed: int):
    from hybrid import make_drive
    from hybrid.ipmc import discrepancy_drive

    if name == "prbs-multilevel":
        return discrepancy_drive(duration, rate, seed)
    return make_drive(name, duration, rate=rate, seed=seed)


#: A hidden effect is *identifiable* when every effect-free fit leaves a held-out MSE
#: of at least this many times the noise variance. The issue asks for a held-out gain
#: ≥ 2, and no model's held-out MSE goes below the noise variance, so below 2× no
#: extension can gain 2×: the paper's cascade absorbs the effect within the noise (a
#: slow strip's many stages mimic a dead time; a smooth V_o does not excite a mode).
#: The effect-free fits are the search's baseline and every effect-free fit as good
#: on training (``evidence["equally_good_effect_free_fits"]``): each is a concrete
#: effect-free simulation, fitted on training data only, so a draw counted as absorbed
#: is shown to be absorbed. A search that missed a better effect-free fit can only
#: count more draws as identifiable, never fewer.
IDENTIFIABLE = 2.0


def draw(effect: str, seed: int, duration: float, rate: float, drive: str, noise: float):
    """(strip, effect parameters, recording) of one draw: the strip and effect from the issue's ranges."""
    from hybrid.ipmc import random_effect, random_strip, synthetic_recording

    rng = np.random.default_rng([seed, len(effect), sum(map(ord, effect))])
    strip, params = random_strip(rng), random_effect(effect, rng, rate)
    recording = synthetic_recording(
        _drive(drive, duration, rate, seed), strip, effect, params, noise_fraction=noise, seed=seed
    )
    return strip, params, recording


def excess_over_noise(recording, found) -> tuple[float, float]:
    """Held-out MSE over the variance of the added noise: the baseline's, and the least of any effect-free fit."""
    hidden = recording.metadata["hidden"]
    noise_var = (hidden["noise_fraction"] * np.ptp(recording.extra["w_true"])) ** 2
    baseline = float(np.mean((found.heldout.w - found.heldout.baseline) ** 2)) / noise_var
    others = found.evidence.get("equally_good_effect_free_fits", {}).get("heldout_nmse_min", float("nan"))
    best = min(1.0, others / found.baseline.heldout.nmse) if np.isfinite(others) else 1.0
    return baseline, baseline * best


def time_line(seconds) -> str:
    """The draws' seconds, compiling included: the median, the max, and the slowest after the first.

    The first draw compiles the search's programs; issue 30 asks that no other
    take more than twice the median.
    """
    median = float(np.median(seconds))
    line = f"diagnose time per recording: median {median:.1f} s, max {max(seconds):.1f} s (the first includes compilation)"
    if len(seconds) > 1:
        later = max(seconds[1:])
        line += f"; after the first, max {later:.1f} s ({later / median:.2f}× the median, compiling included)"
    return line + ".\n"


def time_by_steps(rows) -> str:
    """The draws' seconds less XLA's compiling, against the median, by the number of search steps.

    A diagnosis's time follows its steps (each fits every remaining effect), and
    the first draw compiles the search's programs: compiling is set apart so
    that a slow draw is a slow search, not a first one.
    """
    timed = [r for r in rows if "compiling_seconds" in r]
    if not timed:
        return ""
    running = np.array([r["seconds"] - r["compiling_seconds"] for r in timed])
    median = float(np.median(running))
    steps = np.array([1 + len(r["later_steps"]) for r in timed])
    lines = [
        f"Less XLA's compiling (`jax.monitoring`): median {median:.1f} s, max {running.max():.1f} s "
        f"({running.max() / median:.2f}× the median); compiling {sum(r['compiling_seconds'] for r in timed):.1f} s "
        "in all. By search steps:\n",
        "| steps | draws | running s (median, max) | max / all draws' median |",
        "|---|---|---|---|",
    ]
    for k in sorted(set(steps.tolist())):
        part = running[steps == k]
        lines.append(
            f"| {k} | {part.size} | {np.median(part):.1f}, {part.max():.1f} | {part.max() / median:.2f} |"
        )
    return "\n".join(lines) + "\n"


def _rival_of_named(row, effect: str) -> bool:
    """Whether `effect` is a rival that report.json's `ambiguous` says this recording cannot tell from the cause."""
    return any(a["named"] == row["named"] and effect in a["rivals"] for a in row.get("ambiguous") or [])


def _table(rows, effects, causes) -> str:
    lines = [
        "| hidden \\ named | " + " | ".join(causes) + " | right | right or a rival | gain (median, min) |",
        "|---" * (len(causes) + 4) + "|",
    ]
    for effect in effects:
        mine = [r for r in rows if r["effect"] == effect]
        if not mine:
            continue
        counts = [sum(r["named"] == c for r in mine) for c in causes]
        right = sum(r["named"] == effect for r in mine)
        rival = sum(r["named"] == effect or _rival_of_named(r, effect) for r in mine)
        gains = [r["gain"] for r in mine]
        lines.append(
            f"| {effect} | "
            + " | ".join(str(c) if c else "·" for c in counts)
            + f" | {right}/{len(mine)} | {rival}/{len(mine)} | {np.median(gains):.2f}, {min(gains):.2f} |"
        )
    return "\n".join(lines)


#: A draw with an effect hidden is a *false all-clear* when nothing is named, nothing is left
#: unexplained, and the baseline's held-out MSE exceeds this many times the true noise variance.
ALL_CLEAR = 2.0

#: Effects outside the generator's library list that a later library describes: a hidden
#: ``electrostatic`` is *found* when `diagnose` names this cause (when `CAUSES` has it), and a
#: ``dead_zone`` (on the cascade's output, before the readout) when it names the output's ``dead_band``.
FOUND_AS = {"electrostatic": "even_response", "dead_zone": "dead_band"}


def expected_names(hidden: list[str], causes) -> tuple[list[str], list[str]]:
    """(the causes that would name the hidden effects, the hidden effects no cause describes)."""
    named, outside = [], []
    for name in hidden:
        cause = FOUND_AS.get(name, name)
        (named if cause in causes else outside).append(cause if cause in causes else name)
    return named, outside


def kind_of(expected: list[str], outside: list[str]) -> str:
    """none, single, pair (two or more library effects), outside (only unknown ones) or mixed."""
    if not expected and not outside:
        return "none"
    if not outside:
        return "single" if len(expected) == 1 else "pair"
    return "outside" if not expected else "mixed"


def open_world(found) -> tuple[list[dict], dict | None, object]:
    """(causes, unexplained, noise floor) of a Diagnosis; today's (one cause, no more) reads as one or none."""
    causes = getattr(found, "causes", None)
    if causes is None:
        causes = (
            []
            if found.cause == "none"
            else [{"name": found.cause, "parameters": {}, "incremental_gain": found.gain}]
        )
    return list(causes), getattr(found, "unexplained", None), getattr(found, "noise_floor", None)


def _plain(x):
    """JSON-ready copy (numpy scalars and arrays to floats and lists)."""
    if isinstance(x, dict):
        return {str(k): _plain(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_plain(v) for v in x]
    if hasattr(x, "__array__"):  # numpy and JAX arrays and scalars
        return np.asarray(x).tolist()
    return x


def open_world_row(recording, found, excess: float, causes_known) -> dict:
    """The open-world keys of a row: what was hidden, what was named, what was left unexplained, the noise."""
    from hybrid.ipmc import hidden_effects, true_noise_variance

    hidden = list(hidden_effects(recording))
    expected, outside = expected_names(hidden, causes_known)
    causes, unexplained, floor = open_world(found)
    names = [c["name"] for c in causes]
    true_var = true_noise_variance(recording)
    row = {
        "hidden_effects": hidden,
        "expected_causes": expected,
        "outside_effects": outside,
        "kind": kind_of(expected, outside),
        "causes": names,
        "dropped": [d["name"] for d in getattr(found, "dropped", [])],  # named, then found redundant
        "cause_details": _plain(causes),
        "unexplained": unexplained is not None,
        "unexplained_fraction": None if unexplained is None else float(unexplained["fraction_above_floor"]),
        "unexplained_summary": None
        if unexplained is None
        else str((unexplained.get("description") or {}).get("summary", "")),
        "true_noise_variance": true_var,
        "noise_floor": None if floor is None else _plain(floor.to_dict()),
        "noise_floor_variance": None if floor is None else float(floor.variance),
        "noise_floor_std_error": None if floor is None else float(floor.std_error),
        "noise_floor_over_true": None if floor is None else float(floor.variance) / true_var,
    }
    row["false_all_clear"] = bool(hidden and not names and unexplained is None and excess > ALL_CLEAR)
    start = found.evidence.get("start") or {}
    row["start_flagged"] = bool(start.get("off", False))
    # diagnosed again from a held start (DiagnoseSettings.settle_when_off) and that diagnosis kept: a try
    # that was not kept (delay seed 8 at 744829e: its held start still missed the start) is not counted
    settled = start.get("settled") or {}
    row["start_settled"] = (
        bool(settled.get("automatically") and settled.get("kept", True)) and not row["start_flagged"]
    )
    return row


def told_row(recording, world: dict) -> dict:
    """A pair draw diagnosed again by a search told the hidden effects (`effects=` their causes).

    The search's own rules (held-out gain ≥ 1.5, ΔBIC, materiality, the fits as
    good on training) on the hidden effects alone, with fewer lanes: its baseline
    is refitted from fewer end points, and the as-good bar drawn from fewer fits,
    so it is if anything more lenient than the full search. Where it cannot name
    them all, the recording does not carry each of them clearly enough for those
    rules (after the first, the second can have less than 1.5× the noise left to
    remove: a dead time the network's stages absorb). Where it can and the full
    search does not, another effect won a step, or the full search's lanes found
    an effect-free fit that leaves the hidden effect less to gain.
    """
    from hybrid import diagnose

    found = diagnose(recording, effects=world["expected_causes"])
    causes, unexplained, _ = open_world(found)
    return {
        "causes": [c["name"] for c in causes],
        "gains": [float(c["incremental_gain"]) for c in causes],
        "unexplained": unexplained is not None,
        "seconds": found.seconds,
        "room": room(found, world["expected_causes"], world["true_noise_variance"]),
    }


def room(found, hidden: list[str], noise_variance: float) -> dict | None:
    """Each of two hidden effects' room: the held-out MSE of the other fitted alone over the noise variance.

    `found`: a diagnosis told the hidden effects, whose first step fits each of
    them alone on the baseline. Naming an effect beside the other needs its own
    held-out gain ≥ `min_gain` over the other alone (the step's rule, and
    `drop_redundant`'s when each is weighed as if named last); a fit cannot
    leave less than the noise held out (up to the sampling error of a mean
    square, √(2/n)), so that gain is at most this room. A pair with a room
    below `min_gain` cannot have both named by the rules, whatever the search.
    None: not two effects, or a fit alone is missing.
    """
    if len(hidden) != 2:
        return None
    alone = {c.name: c for c in found.steps[0].candidates}
    if not all(name in alone and alone[name].heldout_residual is not None for name in hidden):
        return None
    return {
        name: float(np.mean(np.square(alone[other].heldout_residual))) / noise_variance
        for name, other in zip(hidden, hidden[::-1])
    }


def _in_reach(r, min_gain: float) -> bool | None:
    """Whether the rules can name both of a pair draw's hidden effects (`room`); None: not known."""
    rooms = (r.get("told") or {}).get("room")
    return None if not rooms else min(rooms.values()) >= min_gain


def start_line(rows) -> str:
    """How many draws `diagnose` said may not start where the simulation does (every strip here starts at rest)."""
    judged = [r for r in rows if "start_flagged" in r]
    if not judged:
        return ""
    flagged = [f"{r['effect']} seed {r['seed']}" for r in judged if r["start_flagged"]]
    settled = [f"{r['effect']} seed {r['seed']}" for r in judged if r.get("start_settled")]
    return (
        f"Start flagged (`evidence.start`; every synthetic strip starts at rest, so each flag is something "
        f"else than a wrong initial state, e.g. a change early in the record): {len(flagged)}/{len(judged)} draws"
        + (f" ({', '.join(flagged)})" if flagged else "")
        + f"; diagnosed again from a held start, which met the start and was kept: {len(settled)}"
        + (f" ({', '.join(settled)})" if settled else "")
        + ".\n"
    )


def _named_set(r) -> str:
    return "{" + ", ".join(sorted(r["causes"])) + "}" if r["causes"] else "∅"


def _names_all(r, causes) -> bool:
    """Whether `causes` include every hidden effect of draw `r` (by its library name)."""
    return set(r["expected_causes"]) <= set(causes)


def _told_all(r) -> bool:
    """Whether the search told a pair draw's hidden effects named them all (`told_row`)."""
    return bool(r.get("told")) and _names_all(r, r["told"]["causes"])


def _flag(r) -> str:
    """How a pair draw that the search did not name fully says something is missing: ``"unexplained"``;
    ``"open"``, its last step left open (report.json's ``ambiguous``, named "none") with a missing hidden
    effect among the rivals; ``"open, other rivals"``; or ``""``: nothing said (a false partial all-clear)."""
    if r["unexplained"]:
        return "unexplained"
    missing = set(r["expected_causes"]) - set(r["causes"])
    opened = [a for a in r.get("ambiguous") or [] if a["named"] == "none"]
    if any(missing & set(a["rivals"]) for a in opened):
        return "open"
    return "open, other rivals" if opened else ""


def _counts(items) -> str:
    items = list(items)
    return (
        "; ".join(f"{k} ×{items.count(k)}" for k in sorted(set(items), key=lambda k: (-items.count(k), k)))
        or "·"
    )


def open_world_tables(rows, specs) -> str:
    """The open-world summary: hidden → named set, pairs, outside effects, effect-free, all-clears, noise floor."""
    from hybrid import DiagnoseSettings

    min_gain = DiagnoseSettings().min_gain  # the held-out gain diagnose asks of a cause: a pair's reach
    out = [
        'Hidden → named set (every draw; ∅: nothing named; "unexpl.": `unexplained` set):\n',
        "| hidden | draws | named sets | unexpl. |",
        "|---|---|---|---|",
    ]
    for spec in specs:
        mine = [r for r in rows if r["effect"] == spec]
        if mine:
            out.append(
                f"| {spec} | {len(mine)} | {_counts(_named_set(r) for r in mine)} | "
                f"{sum(r['unexplained'] for r in mine)}/{len(mine)} |"
            )
    pairs = [s for s in specs if any(r["effect"] == s and r["kind"] == "pair" for r in rows)]
    if pairs:
        out += [
            "",
            "Pairs of library effects (both named: every hidden effect among the named, of which exactly: "
            "nothing else named; one named: some but not all; wrong name(s): named, none of them hidden):\n",
            "| hidden | both named | of which exactly | one named | wrong name(s) | none | unexpl. "
            "| gain (median) | told: both named | both named of those | within the rules' reach |",
            "|---" * 11 + "|",
        ]
        for spec in pairs:
            mine = [r for r in rows if r["effect"] == spec]
            hits = [len(set(r["expected_causes"]) & set(r["causes"])) for r in mine]
            both = [r for r, h in zip(mine, hits) if h == len(r["expected_causes"])]
            exact = sum(set(r["causes"]) == set(r["expected_causes"]) for r in mine)
            one = sum(0 < h < len(r["expected_causes"]) for r, h in zip(mine, hits))
            wrong = sum(h == 0 and bool(r["causes"]) for r, h in zip(mine, hits))
            none = sum(not r["causes"] for r in mine)
            told = [r for r in mine if _told_all(r)]
            out.append(
                f"| {spec} | {len(both)}/{len(mine)} | {exact} | {one} | {wrong} | {none} | "
                f"{sum(r['unexplained'] for r in mine)} | {np.median([r['gain'] for r in mine]):.2f} | "
                f"{len(told)}/{len(mine)} | {sum(r in both for r in told)}/{len(told)} | "
                f"{sum(_in_reach(r, min_gain) is True for r in mine)}/{len(mine)} |"
            )
        every = [r for r in rows if r["kind"] == "pair"]
        told = [r for r in every if _told_all(r)]
        full = [r for r in every if _names_all(r, r["causes"])]
        short = [r for r in every if r.get("told") and not _told_all(r)]
        out += [
            "",
            f"In all: both named {len(full)}/{len(every)}. Told: the draw diagnosed again by a search told the "
            "hidden effects (`diagnose(recording, effects=<their causes>)`, the same rules): it names both in "
            f"{len(told)}/{len(every)}; the full search names both in {sum(r in full for r in told)} of those."
            + (
                " Where the told search names fewer, the recording does not carry each effect clearly enough "
                f"for the rules; told, it names {_counts(_named_set(r['told']) for r in short)} on those."
                if short
                else ""
            ),
        ]
        partial = [r for r in every if not _names_all(r, r["causes"])]
        if partial:
            flags = [_flag(r) for r in partial]
            silent = [r for r, f in zip(partial, flags) if not f]
            out += [
                "",
                f"Not fully named: {len(partial)} draws. Flagged as missing something: "
                f"{flags.count('unexplained')} by `unexplained`; {flags.count('open')} by a last step left open "
                '(report.json\'s `ambiguous`, named "none": a candidate better held out, beside a remainder '
                "above the noise floor or, at the floor, winning significantly many held-out chunks) with a "
                "missing hidden effect among its rivals; "
                f"{flags.count('open, other rivals')} open with other rivals; nothing said on {len(silent)}"
                + (
                    " (" + ", ".join(f"{r['effect']} seed {r['seed']}" for r in silent) + ")"
                    if silent
                    else ""
                )
                + ".",
            ]
        rooms = [r for r in every if _in_reach(r, min_gain) is not None]
        if rooms:
            reach = [r for r in rooms if _in_reach(r, min_gain)]
            out += [
                "",
                "Within the rules' reach (`room`): each hidden effect, fitted alone by the told search, leaves "
                f"the other at least {min_gain}× the true noise variance held out, so each can gain the "
                f"{min_gain}× the rules ask of it beside the other: {len(reach)}/{len(rooms)} draws; the full "
                f"search names both in {sum(_names_all(r, r['causes']) for r in reach)} of those. Out of reach: "
                + (
                    ", ".join(
                        f"{r['effect']} seed {r['seed']} ("
                        + ", ".join(f"{k} {v:.2f}" for k, v in r["told"]["room"].items())
                        + ")"
                        for r in rooms
                        if r not in reach
                    )
                    or "none"
                )
                + ".",
            ]
    outside = [s for s in specs if any(r["effect"] == s and r["kind"] in ("outside", "mixed") for r in rows)]
    if outside:
        out += [
            "",
            "Effects outside the library (unexplained: flagged, whatever was named beside; forced: a "
            "known name and nothing flagged; none: nothing named, nothing flagged — a false all-clear):\n",
            "| hidden | draws | unexplained (fraction above floor, median) | forced into a known name (which) "
            "| none (false all-clear) | library part named |",
            "|---" * 6 + "|",
        ]
        for spec in outside:
            mine = [r for r in rows if r["effect"] == spec]
            flagged = [r for r in mine if r["unexplained"]]
            forced = [r for r in mine if r["causes"] and not r["unexplained"]]
            none = sum(not r["causes"] and not r["unexplained"] for r in mine)
            frac = f" ({np.median([r['unexplained_fraction'] for r in flagged]):.2f})" if flagged else ""
            library = [r for r in mine if r["expected_causes"]]
            part = (
                f"{sum(set(r['expected_causes']) <= set(r['causes']) for r in library)}/{len(library)}"
                if library
                else "—"
            )
            out.append(
                f"| {spec} | {len(mine)} | {len(flagged)}{frac} | {len(forced)} "
                f"({_counts(_named_set(r) for r in forced)}) | {none} | {part} |"
            )
    free = [r for r in rows if r["kind"] == "none"]
    if free:
        named = [r for r in free if r["causes"]]
        flagged = [r for r in free if r["unexplained"]]
        out += [
            "",
            f"Effect-free draws: false discoveries (anything named) {len(named)}/{len(free)}"
            + (f" ({_counts(_named_set(r) for r in named)})" if named else "")
            + f"; false unexplained {len(flagged)}/{len(free)}"
            + (" (seeds " + ", ".join(str(r["seed"]) for r in flagged) + ")" if flagged else "")
            + ".",
        ]
    hidden = [r for r in rows if r["kind"] != "none"]
    if hidden:
        clear = [r for r in hidden if r["false_all_clear"]]
        out += [
            "",
            f"False all-clears (an effect hidden, nothing named, `unexplained` None, while the baseline's "
            f"held-out MSE is > {ALL_CLEAR:g}× the true noise variance): {len(clear)}/{len(hidden)}"
            + (" — " + ", ".join(f"{r['effect']} seed {r['seed']}" for r in clear) if clear else "")
            + ".",
        ]
    floors = [r for r in rows if r["noise_floor_variance"] is not None]
    if floors:
        ratio = np.array([r["noise_floor_over_true"] for r in floors])
        within = sum(
            abs(r["noise_floor_variance"] - r["true_noise_variance"]) <= 2 * r["noise_floor_std_error"]
            for r in floors
            if np.isfinite(r["noise_floor_std_error"])
        )
        out += [
            "",
            f"Noise floor (estimated by `diagnose` from the recording) over the true noise variance: "
            f"median {np.median(ratio):.3f}, range {ratio.min():.3f}–{ratio.max():.3f}; within 2 standard "
            f"errors of the truth in {within}/{len(floors)} draws.",
        ]
        for kind in ("none", "single", "pair", "outside", "mixed"):
            some = [r["noise_floor_over_true"] for r in floors if r["kind"] == kind]
            if some:
                out.append(
                    f"- {kind}: median {np.median(some):.3f}, range {min(some):.3f}–{max(some):.3f} "
                    f"({len(some)} draws)"
                )
    return "\n".join(out)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    jax.config.update("jax_enable_x64", True)
    from hybrid import CAUSES, InputError, RCNetwork, diagnose, resolve_effects
    from hybrid.ipmc import HIDDEN_EFFECTS, HIDDEN_NAMES, canonical
    from hybrid.util import compile_counter

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--effects",
        default=",".join(HIDDEN_EFFECTS),
        help=f"comma-separated hidden specs: {', '.join(HIDDEN_NAMES)}, or several joined by '+' "
        "(e.g. back_relaxation+saturation,none,electrostatic)",
    )
    parser.add_argument("--seeds", type=int, default=10)
    parser.add_argument("--first-seed", type=int, default=0)
    parser.add_argument(
        "--seed-list",
        default=None,
        help="comma-separated seeds (instead of --seeds/--first-seed), e.g. to rerun misses longer",
    )
    parser.add_argument("--duration", type=float, default=120.0)
    parser.add_argument("--rate", type=float, default=30.0)
    parser.add_argument("--drive", default="prbs-multilevel")
    parser.add_argument("--noise", type=float, default=0.01, help="noise std / displacement range")
    parser.add_argument(
        "--search-effects",
        default=None,
        help="comma-separated effects diagnose searches (default: every built-in), e.g. the seven of the "
        "first releases, to measure what the larger set changes on the same draws",
    )
    parser.add_argument("--virtual", action="store_true", help="also diagnose the richer virtual IPMC")
    parser.add_argument(
        "--dry-run",
        action="store_true",
        help="make the recordings and print their truth; no diagnose, nothing written",
    )
    parser.add_argument("--out", default="experiments/results/discrepancy.json")
    args = parser.parse_args(argv)

    try:  # a spec's effects act in physical order: "saturation+back_relaxation" is "back_relaxation+saturation"
        effects = [canonical(e) for e in args.effects.split(",")]
    except InputError as err:
        parser.error(str(err))
    searched = args.search_effects.split(",") if args.search_effects else None
    try:  # a name diagnose does not know is refused here, in one line, not at the first draw
        searched_names = [e.name for e in resolve_effects(searched, RCNetwork())]
    except InputError as err:
        parser.error(str(err))
    if args.seed_list:
        seeds = [int(x) for x in args.seed_list.split(",")]
    else:
        seeds = list(range(args.first_seed, args.first_seed + args.seeds))
    rows = []
    pair_recordings = {}  # (effect, seed) → recording, for the told pass after the loop
    compiling = compile_counter()  # XLA's seconds: a draw's running time is its seconds less them
    for effect in effects:
        for seed in seeds:
            strip, params, recording = draw(effect, seed, args.duration, args.rate, args.drive, args.noise)
            if args.dry_run:
                from hybrid.ipmc import hidden_effects, true_noise_variance

                truth = recording.metadata["hidden"]
                expected, outside = expected_names(list(hidden_effects(recording)), CAUSES)
                print(
                    f"{effect:16s} seed {seed}: {kind_of(expected, outside)}, found as {expected or '-'}, outside "
                    f"{outside or '-'}, noise variance {true_noise_variance(recording):.3g}, {len(recording.w)} "
                    f"samples; {params} {truth.get('derived', '')}",
                    flush=True,
                )
                continue
            compiled_before = compiling["s"]
            found = diagnose(recording, effects=searched)
            compiled = compiling["s"] - compiled_before
            excess, least = excess_over_noise(recording, found)
            world = open_world_row(recording, found, excess, CAUSES)
            if world["kind"] == "pair":
                pair_recordings[effect, seed] = recording
            flagged = f"{world['unexplained_fraction']:.2f} above floor" if world["unexplained"] else "no"
            floor = (
                f"{world['noise_floor_over_true']:5.2f}"
                if world["noise_floor_over_true"] is not None
                else "  n/a"
            )
            print(
                f"{effect:16s} seed {seed}: named {found.cause:16s} gain {found.gain:7.2f}  baseline/noise "
                f"{excess:6.1f}  effect-free/noise {least:6.1f}  ({found.seconds:.0f} s)  {params}",
                flush=True,
            )
            print(
                f"{'':16s}   causes {'+'.join(world['causes']) or '-'}; unexplained {flagged}; noise floor/true "
                f"{floor}{'; FALSE ALL-CLEAR' if world['false_all_clear'] else ''}",
                flush=True,
            )
            rows.append(
                {
                    "effect": effect,
                    "seed": seed,
                    "effect_params": params,
                    "strip": dataclasses.asdict(strip),
                    "named": found.cause,
                    "gain": found.gain,
                    "seconds": found.seconds,
                    "compiling_seconds": compiled,
                    "baseline_mse_over_noise": excess,
                    "effect_free_mse_over_noise": least,
                    "identifiable": bool(least >= IDENTIFIABLE),
                    "baseline_nmse": found.baseline.heldout.nmse,
                    "extended_nmse": found.extended.heldout.nmse,
                    "parameters": found.to_dict()["parameters"] if found.cause != "none" else {},
                    "candidates": {
                        c.name: {
                            "gain": c.gain,
                            "delta_bic": c.delta_bic,
                            "Q": c.ljung_box["Q"],
                            "material": c.material,
                            "eligible": c.eligible,
                            "derived": c.derived,
                            "reasons": c.reasons,
                        }
                        for c in found.candidates
                    },
                    "baseline_Q": found.baseline.ljung_box["Q"],
                    # Each step where the recording cannot tell the named effect from rivals (report.json's
                    # `ambiguous`): a wrong name with the hidden effect among them is said to be uncertain.
                    "ambiguous": [
                        {
                            "step": a["step"],
                            "named": a["named"],
                            "rivals": [v["name"] for v in a["rivals"]],
                            **({"open": True, "evidence": a.get("evidence")} if a.get("open") else {}),
                        }
                        for a in found.ambiguous
                    ],
                    # Each later step's candidates: why a second effect was (not) named.
                    "later_steps": [
                        {
                            "step": k,
                            "chosen": step.cause,
                            "candidates": {
                                c.name: {"gain": c.gain, "eligible": c.eligible, "reasons": c.reasons}
                                for c in step.candidates
                            },
                        }
                        for k, step in enumerate(found.steps[1:], start=2)
                    ],
                    **world,
                }
            )
    if args.dry_run:
        return 0
    # After every draw, so that the draws' times above are one loop of the full search, as before.
    for row in rows:
        recording = pair_recordings.get((row["effect"], row["seed"]))
        row["told"] = None if recording is None else told_row(recording, row)

    virtual = []
    if args.virtual:
        from hybrid.ipmc import virtual_recording

        for drive_name in ("prbs-multilevel", "prbs"):
            recording = virtual_recording(_drive(drive_name, args.duration, args.rate, 0), seed=0)
            found = diagnose(recording, effects=searched)
            print(
                f"virtual IPMC ({drive_name}): named {found.cause} gain {found.gain:.2f} "
                f"{found.extended.derived}",
                flush=True,
            )
            virtual.append(
                {
                    "drive": drive_name,
                    "named": found.cause,
                    "gain": found.gain,
                    "baseline_nmse": found.baseline.heldout.nmse,
                    "extended_nmse": found.extended.heldout.nmse,
                    "parameters": found.to_dict()["parameters"],
                    "candidates": {
                        c.name: {
                            "gain": c.gain,
                            "delta_bic": c.delta_bic,
                            "eligible": c.eligible,
                            "derived": c.derived,
                            "reasons": c.reasons,
                        }
                        for c in found.candidates
                    },
                }
            )

    single = [e for e in effects if e in HIDDEN_EFFECTS]  # the single-effect tables, as before pairs
    table = _table(rows, single, CAUSES)
    table_identifiable = _table(
        [r for r in rows if r["identifiable"] or r["effect"] == "none"], single, CAUSES
    )
    world = open_world_tables(rows, effects)
    seconds = [r["seconds"] for r in rows]
    command = "python experiments/discrepancy.py " + " ".join(argv)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(
        json.dumps(
            {"command": command, "settings": vars(args), "rows": rows, "virtual_ipmc": virtual},
            indent=2,
            default=float,
        )
    )
    summary = [
        "# Discrepancy search: hidden effect × named cause\n",
        f"Command: `{command}`\n",
        f"Drive {args.drive}, {args.duration:g} s at {args.rate:g} Hz, noise {100 * args.noise:g} % of range, "
        f"seeds {', '.join(map(str, seeds))}.\n",
        f"Effects searched: {'every built-in' if searched is None else 'only'} ({', '.join(searched_names)}).\n",
    ]
    if single:
        summary += [
            "All draws (right or a rival: the hidden effect named, or among the rivals report.json's "
            "`ambiguous` says this recording cannot tell from the named cause):\n",
            table,
            "",
            f"Draws whose effect is identifiable (every effect-free fit leaves a held-out MSE ≥ "
            f"{IDENTIFIABLE:g}× the noise variance, so a gain of 2 is possible; all effect-free draws):\n",
            table_identifiable,
            "",
        ]
    summary += ["## Open world: several causes, effects outside the library, the noise floor\n", world, ""]
    if seconds:
        summary.append(time_line(seconds))
        summary.append(time_by_steps(rows))
    summary.append(start_line(rows))
    for v in virtual:
        summary.append(f"Virtual IPMC ({v['drive']}): named **{v['named']}**, held-out gain {v['gain']:.2f}.")
    out.with_suffix(".md").write_text("\n".join(summary) + "\n")
    if single:
        print(table)
        print(table_identifiable)
    print(world)
    single_rows = [r for r in rows if "+" not in r["effect"] and not r.get("outside_effects")]
    hits = sum(r["named"] == FOUND_AS.get(r["effect"], r["effect"]) for r in single_rows)
    print(
        f"single effects (and none) named right: {hits}/{len(single_rows)}; wrote {out} and {out.with_suffix('.md')}"
    )
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
