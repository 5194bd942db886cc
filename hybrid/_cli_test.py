"""`hybrid fit --test FILE ...`: the fitted model scored on records it was not fitted to.

A benchmark keeps an estimation record and a validation record (Cascaded Tanks:
``uEst -> yEst`` and ``uVal -> yVal`` in one CSV). `fit` fits the estimation
record(s) and then runs the fitted model free on each ``--test`` record: the
simulation from its own initial state (rest for ``lti:N`` and the RC network; a
plug-in says, e.g. `TwoTank` starts in equilibrium with the first sample's
drive), driven by the record's input only (the
measured output is never fed back; every model here is non-autoregressive). A
hybrid model's D-MLP needs ``window`` samples of history: as for the fit's own
test split (`hybrid.core._windows`), the first window − 1 samples see the
simulation's first value held before the record began (edge padding), and every
sample is scored.

A test record is read with the fitted recordings' mapping options (``--input``,
``--output``, ``--columns``, ``--time``, ``--rate``, ``--units``, ``--range``)
through `hybrid.data._mapping.load_pair`; ``--test-columns`` and ``--test-range``
replace the columns and the samples. It must have the fitted recordings' rate.

With ``--settle`` (the physics held at a fitted constant drive before the
record, `hybrid.HeldStart`) a test record starts from its own state, which the
fitted record's ``initial_drive`` does not know: it alone is re-fitted on the
test record's first 2.5 % of samples (at least 10; `initial_samples`), every
other parameter fixed, and every sample is scored; the score says how many.
"""

from __future__ import annotations

import sys

import numpy as np

from .util._errors import InputError

#: The fewest samples of a test record that `--initial-samples` may leave to score: a score on one sample
#: has no variance to normalise by (a probe's N − 1 ran the whole fit, then failed on "w is constant").
MIN_SCORED = 10

_MAPPING = ("input", "output", "time", "columns", "rate", "sample_range", "units", "fill_gaps")


def add_test_options(p) -> None:
    """--test, --test-columns, --test-range on `hybrid fit`."""
    g = p.add_argument_group("scoring on other records (a benchmark's validation record)")
    g.add_argument(
        "--test",
        nargs="+",
        default=None,
        metavar="FILE",
        help="after the fit, run the fitted model free (the simulation from its own initial state, rest "
        "for lti:N and rc, driven by the input alone) on each FILE and report RMSE (in the output's unit), NMSE and the number of "
        "samples; a hybrid model's first window-1 samples see the first value held before "
        "(edge padding, as the fit's own test split) and are scored. Read with the fit's "
        "column options; --split still splits the fitted recordings only",
    )
    g.add_argument(
        "--test-columns",
        default=None,
        metavar="MAP",
        help="the test records' own columns, e.g. input=uVal,output=yVal (default: the fit's)",
    )
    g.add_argument(
        "--initial-samples",
        type=int,
        default=None,
        metavar="N",
        help="the benchmark's rule: at most the first N samples of a test record may set its initial "
        "state (with --settle its held drive is re-fitted on them), and the score is taken over the "
        f"rest, at least {MIN_SCORED} (Cascaded Tanks 4, Silverbox 50). Default: every sample is scored; --settle re-fits on "
        "the first 2.5 %% (at least 10)",
    )
    g.add_argument(
        "--test-range",
        default=None,
        metavar="START:STOP",
        help="the test records' samples, Python-slice style (default: the fit's --range, else all)",
    )


def load_tests(args, fitted, window: int) -> list:
    """The --test records, checked before any fitting: their columns, their rate, their length."""
    from .core._problem import unmeasured_of
    from .data._loaders import MissingName
    from .data._mapping import RATE_RTOL, load_mapped, load_pair
    from .data._recording import Recording, in_shared_units
    from .data._recording_checks import mapped_by, ranged_by

    first = getattr(args, "initial_samples", None)
    if not args.test:
        if args.test_columns is not None or args.test_range is not None or first is not None:
            raise InputError(
                "--test-columns, --test-range and --initial-samples describe the --test records: give --test FILE"
            )
        return []
    options = {k: getattr(args, k, None) for k in _MAPPING}
    mapped = any(v is not None for v in options.values())
    if not mapped and (args.test_columns is not None or args.test_range is not None):
        raise InputError(
            "--test-columns and --test-range map a lab's file, and the fitted recordings are read in "
            "the project's own columns t, v_in, w: map them too, e.g. --columns t=t,input=v_in,output=w"
        )
    # --units (--rate, --fill-gaps) alone on files in the project's own columns: read as the fitted ones
    # are (through load_pair, which needs named columns, a probe's --units w=mm refused its --test file)
    own_columns = args.test_columns is None and all(
        options[k] is None for k in ("input", "output", "time", "columns")
    )
    test_range = args.test_range if args.test_range is not None else args.sample_range
    tests = []
    # a message about a test record names --test-range as what cuts it: --range would cut the fitted ones,
    # and names --test-columns as what maps its columns: --columns would map the fitted ones
    with ranged_by("--test-range"), mapped_by("--test-columns"):
        for path in args.test:
            # a text table of t, v_in, w: read as `hybrid fit` reads a fitted one
            if not mapped and own_text_table(path):
                try:
                    record = load_mapped(path, input="v_in", output="w", time="t")
                except InputError as error:
                    raise InputError(f"--test {path}: {error}") from None
            elif not mapped:
                try:
                    record = Recording.load(path)  # the project's own columns, as the fitted recordings
                except MissingName as error:  # --test-columns maps it where the fitted ones are mapped too
                    raise InputError(
                        f"--test {path}: {error}; with --test-columns, map the fitted recordings' own columns "
                        "too: --columns t=t,input=v_in,output=w"
                    ) from None
                except InputError as error:
                    raise InputError(f"--test {path}: {error}") from None
            else:
                try:  # the fitted recordings have loaded: what fails here is the test record's
                    if own_columns:
                        given = {k: v for k, v in options.items() if v is not None and k != "sample_range"}
                        record = Recording.load(path, **given, sample_range=test_range)
                    else:
                        _, record = load_pair(
                            args.recordings[0],
                            test_path=path,
                            test_columns=args.test_columns,
                            test_sample_range=test_range,
                            **options,
                        )
                except InputError as error:
                    raise InputError(f"--test {path}: {error}") from None
            record = in_shared_units([fitted[0], record], f"--test {path}")[1]  # scored in the fitted units
            for note in record.notes:
                print(f"hybrid: warning: {note}", file=sys.stderr)
            # a rate the model was fitted at: one of the fitted records' (a fit of records at 30 and 25 Hz
            # refused every test record, each against one rate or the other, a probe)
            if not any(abs(record.rate - r.rate) <= RATE_RTOL * r.rate for r in fitted):
                rates = " and ".join(dict.fromkeys(f"{r.rate:.6g} Hz" for r in fitted))
                raise InputError(
                    f"test record '{record.name}' is sampled at {record.rate:.6g} Hz but the model is fitted at "
                    f"{rates} ('{fitted[0].name}'{' and more' if len(fitted) > 1 else ''}): score on records of "
                    "a fitted rate"
                )
            for fitted_path, recording in zip(args.recordings, fitted):
                if _key(path, record) == _key(fitted_path, recording):
                    raise InputError(
                        f"test record '{record.name}' is a fitted record: give other columns "
                        "(--test-columns), other samples (--test-range) or another file"
                    )
            record.check_length(
                window, f"the model's input window ({window} samples)", "give a longer test record"
            )
            record.check_signals()
            if first is not None and not 1 <= first <= record.n - MIN_SCORED:
                raise InputError(
                    f"--initial-samples {first}: test record '{record.name}' has {record.n} samples, and at least "
                    f"{MIN_SCORED} must be left to score; give a number from 1 to {record.n - MIN_SCORED} (the "
                    "benchmark's rule, e.g. 4 for Cascaded Tanks)"
                )
            # a quality column's 0s are not scored (`score_tests`)
            unmeasured = unmeasured_of(record)
            left = int(np.sum(~unmeasured[first or 0 :]))
            if left < MIN_SCORED:
                raise InputError(
                    f"test record '{record.name}' has {left} samples of quality 1 to score"
                    + (f" after its first {first}" if first else "")
                    + f" (at least {MIN_SCORED} are needed; quality 0: w not measured there): track its video "
                    "again, or test on a record whose w was measured"
                )
            tests.append(record)
    return tests


def own_text_table(path) -> bool:
    """Whether `path` is a text table (.txt, .dat, .tsv, ...) whose header has the columns t, v_in and w.

    `hybrid fit` reads such a table as the project's own columns; its --test record of the same kind
    was refused ("unknown suffix '.txt'", a verifier's), and --test-columns could not map it alone.
    """
    from pathlib import Path

    from .data._loaders import TEXT_SUFFIXES
    from .data._mapping import header_names

    return Path(path).suffix.lower() in TEXT_SUFFIXES and {"t", "v_in", "w"} <= set(header_names(path))


def _key(path, recording) -> tuple:
    """The file, the columns and the samples: equal keys are the same record."""
    from pathlib import Path

    meta = recording.metadata
    return Path(path).resolve(), repr(meta.get("mapping")), repr(meta.get("segment"))


def score_tests(model, tests, first: int | None = None) -> list[dict]:
    """Each test record's free-run score: rmse (the output's unit), the NMSEs of `hybrid.metrics`, samples.

    `first` (``--initial-samples``): at most these first samples may set the
    record's initial state, and the score is taken over the rest.
    """
    from .core._held_start import has_held_start, refit_initial_drive
    from .core._metrics import metrics
    from .core._problem import unmeasured_of
    from .discovery._start import misfit_at_start, start_shape

    scores = []
    for record in tests:
        held = {}
        scored = model
        if has_held_start(model.simulation):  # --settle: the record starts from its own state
            samples = initial_samples(record.n) if first is None else first
            scored, value = refit_initial_drive(model, record, samples)
            held = {"initial_drive": value, "initial_samples": samples}
        w_hat = np.asarray(scored.predict(record.v_in, record.dt))  # the whole record: one segment
        w = np.asarray(record.w)
        # a quality column's 0s: w was not measured there
        unmeasured = unmeasured_of(record)
        if not held and np.all(np.isfinite(w_hat)):  # a start no held drive can meet: said, not scored away
            start = misfit_at_start([np.where(unmeasured, np.nan, w - w_hat)], [record.name], settled=False)
            if start["off"]:
                row = start["recordings"][0]
                held = {  # what the score line says of the record's start (here: that nothing set it)
                    "start": {
                        "off": True,
                        "ratio": row["ratio"],
                        "first_samples": row["first_samples"],
                        "sentence": (
                            f"the model misses its first {row['first_samples']} samples by {row['ratio']:.1f}× "
                            f"its RMS on the rest, {start_shape(row)}: the record does not start where the model "
                            "does, and the model has no held start for "
                            + (
                                f"--initial-samples {first} to set (those samples are only left out of the "
                                "score)"
                                if first is not None
                                else "its first samples to set (every sample is scored)"
                            )
                            + "; fit with --settle N to let them set the record's initial drive"
                        ),
                    }
                }
        scored_samples = ~unmeasured
        if first is not None:  # the samples that may set the state are not scored
            scored_samples[:first] = False
            held = {**held, "initial_samples": first, "scored_from": first}
        if not scored_samples.any():
            raise InputError(
                f"test record '{record.name}': no sample is left to score (quality 0 throughout"
                + (f" after its first {first} samples" if first is not None else "")
                + "): track its video again, or test on a record whose w was measured"
            )
        if unmeasured[first or 0 :].any():  # left out of the score, and said
            held = {**held, "unmeasured": int(np.sum(unmeasured[first or 0 :]))}
        w, w_hat = w[scored_samples], w_hat[scored_samples]
        if not np.all(np.isfinite(w_hat)):
            raise InputError(
                f"the fitted model's prediction for test record '{record.name}' is not finite: "
                "the record drives it far outside the fitted range"
            )
        units = record.metadata.get("units") if isinstance(record.metadata.get("units"), dict) else {}
        meta = record.metadata
        scores.append(
            {
                "name": record.name,
                "source": str(meta.get("source", "")),
                "mapping": meta.get("mapping"),
                "segment": meta.get("segment"),
                "samples": int(w.shape[0]),
                "rate_hz": float(record.rate),
                "unit": str(units.get("w", "mm")),
                "rmse": float(np.sqrt(np.mean((w - w_hat) ** 2))),
                **metrics(w, w_hat),
                **held,
            }
        )
    return scores


def initial_samples(n: int) -> int:
    """How many of a test record's first samples set its own held drive (--settle): 2.5 %, at least 10."""
    return int(min(n, max(10, round(0.025 * n))))


def print_scores(scores) -> None:
    for s in scores:
        print(
            f"  test record {s['name']}: RMSE {s['rmse']:.6g} {s['unit']}  NMSE {s['nmse']:.3e}  "
            f"NMSE(variance) {s['nmse_variance']:.3e}  Fitting {s['fitting']:6.2f} %  ({s['samples']} samples)"
            + (
                f"; initial_drive {s['initial_drive']:.6g} re-fitted on its first {s['initial_samples']} samples"
                if "initial_drive" in s
                else ""
            )
            + (f"; scored after its first {s['scored_from']} samples" if "scored_from" in s else "")
            + (f"; {s['unmeasured']} samples of quality 0 left out of the score" if "unmeasured" in s else "")
        )
        if "start" in s:
            print(f"  start: test record {s['name']}: {s['start']['sentence']}")
