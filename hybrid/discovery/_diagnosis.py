"""What `diagnose` is told and what it returns: its settings, a candidate's fit and evidence, the diagnosis.

`DiagnoseSettings` (how the search fits and decides), `Candidate` (one
effect's extended fit with its evidence), `Diagnosis` (the answer;
``to_dict()`` is ``report.json``), the typed results they carry
(`HeldoutMetrics`, `ParameterUncertainty`, `EquallyGoodFits`, `Lane`,
`HeldoutSignals`), and the names they share: `CAUSES` and `SPLIT_ORDER`.
Results travel between the modules of the search as these objects; they
become dicts only in `to_dict()`, the edge that writes ``report.json``.
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING

import numpy as np

from ..core._fit import PAPER_UNITS
from ..util._errors import InputError
from ._ambiguity import TEST as AMBIGUITY_TEST, unlike
from ._effect_set import EFFECTS, NAMED_ONLY
from ._effects import FrameTiming, thresholds_of

if TYPE_CHECKING:
    from ._noise_floor import NoiseFloor
    from ._step import Step

#: Names `diagnose` can return: an effect of `hybrid.discovery._effects`, or "none".
CAUSES = ("none",) + tuple(EFFECTS) + tuple(NAMED_ONLY)
#: report.json's schema.
#: - 4 (from 3): the last key that named a unit, ``evidence.<model>.loop_separation_mm``, is
#:   ``loop_separation`` (in w's unit); ``units`` gives the recorded signals' units (``w``, ``v_in``).
#: - 3 (from 2): no key carries a unit in its name, since an effect's unit follows the signal it
#:   acts on (its ``unit`` field says which): ``saturation_pos_per_v`` / ``_neg_per_v`` are
#:   ``saturation_pos_curvature`` / ``_neg_curvature``, ``hysteresis_height_v`` is
#:   ``hysteresis_height``, ``hysteresis_rate_per_v`` is ``hysteresis_rate``, ``even_per_v`` is
#:   ``even_coefficient``, and saturation's derived ``level_pos_v`` / ``level_neg_v`` are
#:   ``level_pos`` / ``level_neg``. Names of time and frequency (``delay_s``, ``_hz``) keep theirs:
#:   those units never change. ``places`` says where effects were searched. ``baseline_drift``
#:   gains a cubic term, ``baseline_cubic_per_min3``; the drive's new effects add their keys.
#: - 2 (from 1): each parameter with a standard error says whether the recording pins it
#:   (``pinned``; ``not_pinned``: why not); units follow the signal an effect acts on;
#:   ``effects`` lists the searched effects and where each acts; ``settings.materiality`` lists
#:   every threshold used.
#: Keys added within schema 3 (a reader of 3 may ignore them): ``ambiguous`` (each step whose named
#: cause has rivals this recording cannot tell apart, and an open last step: ``"named": "none"``,
#: ``"open": true``), ``ambiguity_test`` (the test, in words), ``dropped`` (named causes the
#: final model did not need, each weighed as if named last), each cause's ``step`` and
#: ``evidence.start`` (whether each recording starts where the simulation does) with
#: ``evidence.start.settled`` (the held start diagnose tried by itself, and what the run from the
#: simulation's own start named); a limit on a state that spills adds ``<state>_spill``; hysteresis's
#: ``derived`` and thresholds add ``loop_rate_times_range`` (the loop must close over the recording).
#: Within schema 4: a cause's ``derived_units`` (the units of its derived quantities that their names do
#: not say: a saturation's ``level_pos``/``level_neg`` in the unit of the signal it acts on); each
#: ``ambiguous`` rival's ``named_better`` (the held-out tests prefer the named cause: listed because the
#: two predict alike to within the noise, not because the recording cannot tell them); the evidence's
#: ``baseline``/``extended`` ``drive_independence`` (the held-out residual's independence of the drive,
#: `residual_tests.drive_independence`; null where it cannot be tested), and the same test of the
#: remainder in ``unexplained.description.drive_independence``; ``noise_floor.glitches`` (runs of a
#: few samples that w jumps into and back out of, each [first, last], left out of the floor with the
#: isolated spikes; their samples are in ``noise_floor.spikes`` too); ``glitches_bridged`` (those runs
#: bridged before any fit, per recording: ``DiagnoseSettings.bridge_glitches``, on by default, so that
#: ``noise_floor.glitches`` is empty unless it is off; an entry's ``unmeasured``: the runs of a
#: ``quality`` column's 0s inside the record, bridged alike, and ``unmeasured_ends``, those at its start
#: or end, left as recorded; all of them are left out of every fit and score) and ``settings.bridge_glitches``;
#: ``noise_floor.method`` ``rounding`` (the floor is the rounding of w's values to a coarse grid); each
#: parameter's ``to_training_optimum`` and ``at_training_optimum`` (`OFF_OPTIMUM`); ``evidence.refined``
#: (the second diagnosis with a named-only refinement in its parent's place, `DiagnoseSettings.refine`),
#: ``unexplained.description.named_only`` (the named-only built-in the remainder points at) and
#: ``settings.refine``; an output-side cause's ``as_recorded`` (its `levels`, a saturation's, where w
#: levels off: through the readout, in ``as_recorded_unit``, w's); a saturation's ``level_pos`` or
#: ``level_neg`` is left out of ``derived`` where the signal never reaches that side's knee
#: (`REACHED_PERCENT`: its shortfall says how far it stays from it); ``unexplained.description.time``
#: may read ``"form": "wander"`` (straight pieces over the record, `_time_wander`), with the change at one
#: time it beat under ``step``; ``evidence.start.settled`` gains ``kept`` (whether the held diagnosis is
#: the one reported) and, where the named causes met a start the effect-free model missed
#: (`covered_try`), ``effect_free_ratio`` and ``without.gain_over_held``; ``evidence.drive_range``
#: ([least, largest] drive of the diagnosed recordings, in the drive's unit: where the rivals were
#: fitted, which ``hybrid design`` says a drive beyond leaves); a hysteresis's ``derived`` gains
#: ``turn_percent_of_range`` (how far the signal it acts on turns back); each cause's ``place`` (where it
#: acts: ``drive``, ``inside`` or ``output``); each ``dropped`` entry's ``beside`` (the causes it was weighed
#: beside; empty: against the effect-free baseline, where it was the one left after a drop); a cause's
#: ``points_at`` (the effect searched only when named that its fit stands in for,
#: `AbstractEffect.points_at`); an even part's ``derived`` gains ``turn_percent_of_range`` (where its map
#: turns, from the end it rises from, beyond 100 where past the range); each ``ambiguous`` rival of a
#: named cause's ``why`` (the entry's reasons that concern that rival: a level and time correlated says
#: nothing of two effects of the level), and each entry's ``recordings`` (how many were diagnosed together);
#: a candidate's ``raced`` (false where its effect left the search's race after ``settings.start_steps`` LM
#: steps, trailing the ``settings.racing_effects`` leading effects: its numbers are that short fit's).
REPORT_SCHEMA = "hybrid-report/4"
#: The keys schema 3 and 4 renamed, old → new (a reader of older reports may map them).
RENAMED_IN_SCHEMA_3 = {
    "saturation_pos_per_v": "saturation_pos_curvature",
    "saturation_neg_per_v": "saturation_neg_curvature",
    "hysteresis_height_v": "hysteresis_height",
    "hysteresis_rate_per_v": "hysteresis_rate",
    "even_per_v": "even_coefficient",
    "level_pos_v": "level_pos",
    "level_neg_v": "level_neg",
}
RENAMED_IN_SCHEMA_4 = {"loop_separation_mm": "loop_separation"}

SPLIT_ORDER = ("train", "validation", "test")
#: The fewest samples `diagnose` reads a recording from (a held-out part long enough for residual tests);
#: `design_drive` and `rich_drive` make no shorter drive.
MIN_DIAGNOSE_SAMPLES = 60
#: The most blocks `diagnose` splits a recording into to reach its extremes, as a multiple of
#: `DiagnoseSettings.blocks` (`DiagnoseSettings.held_out_limits`).
MAX_BLOCKS_FACTOR = 2


@dataclasses.dataclass(frozen=True)
class DiagnoseSettings:
    """How `diagnose` fits and decides (every field is written to the report).

    - `split`, `blocks`: each recording is cut into `blocks` equal chunks and each
      chunk into train, validation, test by the fractions `split`, in that order.
      Blocks make every part span the recording: on a strip slower than the
      recording, a held-out tail visits displacements the training part never
      reached (hysteresis seed 2 of `experiments/discrepancy.py`: the training
      36 s stay below −2 mm, the held-out 18 s rise to +2.5 mm), and no fit —
      with or without the right effect — predicts it; blocks make the held-out
      error one of interpolation.
    - `held_out_limits`: the held-out parts must see where a recording sits
      flat at its largest or smallest value (`flat_extremes`: an overflow, an
      end stop, a sensor's range), or a limit there is tested on training data
      alone: the Cascaded Tanks' estimation record overflows twice, and with 3
      blocks both lie in training parts. Where `blocks` leaves a side's flat
      runs out of every held-out part, the fewest blocks up to
      `MAX_BLOCKS_FACTOR` × `blocks` whose held-out parts include some of them
      are used (`held_out_blocks`), and the report's split says so; where none
      does, `blocks`. False: `blocks` as given.
    - `blocks_used`, `extremes_held_out`: the blocks the search split each
      recording into, and whether its held-out parts see those flat runs; None
      until `diagnose` completes the settings (`split_blocks` reads the first).
    - `max_steps`: most LM steps of any lane.
    - `patience`: a candidate's lane stops after this many accepted steps
      without a better validation loss.
    - `start_steps`: the LM steps every candidate lane takes before an effect
      with more lanes than it keeps (`AbstractEffect.n_kept`) keeps its best
      and the effects beyond `racing_effects` leave (the race's first round;
      0: no first round, nothing culled, every effect races).
    - `racing_effects`: where a step has more candidate effects on the drive and
      the output than this (or the joint fit more pairs, `JOINT_LEADERS`), every
      lane takes the first round's `start_steps` LM steps, and only the effects
      (pairs) whose best lane then has the least validation loss, this many,
      race on, beside every effect inside the dynamics (a limit acts only where
      its state reaches it: its first steps move the fit least); the others
      keep that short fit (their candidates' ``raced`` is false), are not
      refitted from, and are weighed as any candidate. The search's
      time then grows with the effects it is given only by that round
      (`benchmarks/diagnose_effect_set.py`, docs/benchmarks.md); 7 is the
      original effect set's size, whose searches it leaves as they were.
      0: every effect races.
    - `race_patience`: a candidate's lanes first run to this shorter patience;
      then each effect's leading lanes (the least validation loss, and those
      the rest of the patience could bring level with it) go on where they
      stopped until `patience`: the steps they would have taken with it from
      the start. The others keep their first result. 0: every lane runs to
      `patience`.
    - `effect_free_patience`: the same for the baseline's and re-baseline's lanes.
      Most effect-free lanes are done within a few steps of their best (on the
      5-minute benchmark recording, timed ad hoc: 10 instead of 25 took the
      baseline stage from 15 s to 5 s, the re-baseline from 9 s to 6 s, same
      cause and gain). A candidate lane needs the longer patience: with 10,
      delay seed 10 of `experiments/discrepancy.py` stopped at a held-out gain
      of 1.6 that 25 steps take to 2.7.
    - `patience_rtol`: an accepted step counts as a better validation loss, for both
      patiences, only when it improves the lane's best by more than this fraction
      (see `LMSettings.patience_rtol`).
    - `min_gain`: held-out NMSE ratio baseline/extended needed to name a cause.
    - `min_bic_drop`: BIC decrease (training part) needed to name a cause.
    - `materiality`: overrides, by name, of the effects' own thresholds for the
      smallest size that counts as a cause (`AbstractEffect.thresholds`, e.g.
      ``{"delay_samples": 2.0}``); below it the "effect" is within timing or
      modelling slack. The report shows every threshold the search used.
    - `max_causes`: most causes named, one per step of the stepwise search.
    - `unexplained_ratio`: the final model's held-out MSE above this multiple of
      the noise floor (taken at the top of its ±2 standard errors) is reported as
      ``unexplained``: 2 means more than half of the held-out error lies above
      the measurement noise. Fits of the right model in
      `experiments/discrepancy.py` leave 0.9–1.5× the noise held out when the
      recording pins the strip.
    - `frozen`: parameters never fitted; ``None`` (default) takes the
      simulation's `frozen_by_default` (the RC network's ξh: only ξρ/ξh is
      identifiable).
    - `settle_when_off`: when the final model misses one recording's start
      (``evidence.start``: the record may not start where the simulation
      does), diagnose it again with the simulation held at a fitted drive
      first ([`HeldStart`][], a quarter of the record's samples) and keep that
      diagnosis if its start then fits; if it does not, the first stands and
      says so. Not for a simulation already held, nor for several recordings
      (one held drive cannot start them all). False: say it, do not try.
    - `bridge_glitches`: put each of w's glitches (`glitch_runs`: a run of 2 to
      `GLITCH_RUN` samples that w jumps into and back out of, undriven: a
      tracker that lost its marker, a logger that read 0) on the straight line
      between its neighbours before any fit, and say so in ``warnings`` and
      ``glitches_bridged``. Left in, each is a residual no model of the plant
      fits, which bends every fit and dilutes every gain. So are the runs of
      samples a ``quality`` column (rig's) marks 0 inside the record: w was
      held there, not measured (``glitches_bridged``'s ``unmeasured``). False
      (the CLI's ``--keep-glitches``): keep them as recorded (a relay, a
      contact that chatters: the system's own flips); the noise floor still
      leaves glitches out and says so.
    - `refine`: where the default effect set names an effect that has a
      `refinement` (a saturation: a clip, its knee's sharpness fitted) and
      leaves `min_gain` times the noise floor or more held out, or the
      remainder points at a refinement, diagnose again with the refinement in
      its place, and keep that diagnosis where it names the refinement and its
      extended model's held-out NMSE is `min_gain` times lower
      (``evidence.refined`` says what came of it where it was tried). False:
      not tried.
    """

    split: tuple[float, float, float] = (0.6, 0.1, 0.3)
    blocks: int = 3
    held_out_limits: bool = True
    blocks_used: int | None = None
    extremes_held_out: bool | None = None
    max_steps: int = 120
    patience: int = 25
    start_steps: int = 6
    racing_effects: int = 7
    race_patience: int = 10
    effect_free_patience: int = 10
    patience_rtol: float = 1e-3
    min_gain: float = 1.5
    min_bic_drop: float = 10.0
    materiality: dict = dataclasses.field(default_factory=dict)
    frozen: tuple[str, ...] | None = None
    max_causes: int = 3
    unexplained_ratio: float = 2.0
    settle_when_off: bool = True
    bridge_glitches: bool = True
    refine: bool = True

    def materiality_for(self, effects) -> dict:
        """Every threshold of `effects` (`AbstractEffect.thresholds`), with `materiality`'s overrides."""
        out = {k: v for effect in effects for k, v in effect.thresholds.items()}
        unknown = sorted(set(self.materiality) - set(out))
        if unknown:
            raise InputError(
                f"materiality (--materiality, DiagnoseSettings.materiality) names {unknown}, which no searched "
                "effect has; "
                f"the thresholds are {sorted(out)}"
            )
        bad = {k: v for k, v in self.materiality.items() if not (math.isfinite(v) and v >= 0)}
        if bad:
            raise InputError(
                f"materiality (--materiality, DiagnoseSettings.materiality) takes a size ≥ 0, got {bad}"
            )
        return {**out, **self.materiality}

    @property
    def split_blocks(self) -> int:
        """The blocks each recording is split into: `blocks_used` once chosen, else `blocks`."""
        return self.blocks if self.blocks_used is None else self.blocks_used

    def frozen_for(self, simulation) -> tuple[str, ...]:
        """`frozen`, or the simulation's parameters frozen by default when it is None."""
        return tuple(simulation.frozen_by_default) if self.frozen is None else tuple(self.frozen)


@dataclasses.dataclass(frozen=True)
class HeldoutMetrics:
    """A fit's errors on the held-out (test) part, all recordings together (`hybrid.core.metrics`)."""

    nmse: float
    """MSE / var(w): the system-identification NMSE that gains and decisions use."""
    nmse_eq18: float
    """The paper's Eq 18 NMSE (each signal divided by its own peak |.|): blind to a wrong gain."""
    nmse_target: float
    """MSE / mean(w²)."""
    nmse_variance: float
    """MSE / var(w) as `hybrid.core.metrics` names it (the same number as `nmse`)."""
    fitting: float
    """The paper's fitting percentage."""


#: Standard errors between a reported value and the training part's optimum (`Covariance.to_optimum`)
#: beyond which the report says the value is not that optimum: an LM lane keeps the iterate with the
#: best validation loss, and on a short validation part that can be an early one (a plug-in
#: pendulum's frame lag was kept at its start, several standard errors from the training optimum).
OFF_OPTIMUM = 2.0


@dataclasses.dataclass(frozen=True)
class ParameterUncertainty:
    """The standard error of one fitted parameter, in its physical unit (`parameter_uncertainties`)."""

    std_error: float
    """Gauss–Newton standard error on the training part, inflated by `inflation`."""
    unit: str
    """The parameter's physical unit."""
    inflation: float
    """Variance inflation for the held-out residual's autocorrelation (`effective_sample_factor`)."""
    std_error_given_network: float | None = None
    """Standard error with the simulation's own parameters held at their fitted values (None for those)."""
    to_optimum: float | None = None
    """The training part's optimum less the value, from Gauss–Newton steps (`Covariance.to_optimum`)."""
    diverged: bool = False
    """Whether the model's derivative diverged at its values (`Covariance.diverged`): no error can be read."""

    @property
    def held_off_optimum(self) -> bool:
        """The value lies more than `OFF_OPTIMUM` standard errors from the training part's optimum."""
        step, se = self.to_optimum, self.std_error
        return step is not None and math.isfinite(step) and math.isfinite(se) and abs(step) > OFF_OPTIMUM * se


@dataclasses.dataclass(frozen=True)
class EquallyGoodFits:
    """Held-out spread of the fits of the current model as good on training data (`equally_good_fits`)."""

    n: int
    """How many fits are within the BIC tolerance of the current model's training error."""
    heldout_nmse_min: float
    """Their least held-out NMSE (nan if none): the bar an effect's gain must also clear."""
    heldout_nmse_max: float
    """Their largest held-out NMSE (nan if none)."""
    definition: str
    """Which fits count, in words."""

    def to_dict(self) -> dict:
        """As in ``report.json``'s ``evidence["equally_good_effect_free_fits"]``."""
        return {
            "n": self.n,
            "heldout_nmse_min": self.heldout_nmse_min,
            "heldout_nmse_max": self.heldout_nmse_max,
            "definition": self.definition,
        }


@dataclasses.dataclass(frozen=True)
class Lane:
    """One candidate lane of a step of the search (not in ``report.json``)."""

    effect: str
    """The effect the lane switches on beyond those already named."""
    step: int
    """The step of the stepwise search it belongs to (1: the first)."""
    validation_loss: float
    """½ mean r² on the validation part at its best point."""
    chosen: bool
    """Whether it stands for its effect in its step (`choose_lane`)."""
    theta: np.ndarray
    """Its end point, in the layout of `lanes_problem`'s θ (``experiments/diagnose_lanes.py`` reads it)."""
    active: np.ndarray
    """Its effects' switches."""


@dataclasses.dataclass(frozen=True)
class HeldoutSignals:
    """Held-out signals, all recordings' test parts concatenated (one entry per sample)."""

    t: np.ndarray
    """Time (s) within its recording."""
    v_in: np.ndarray
    """Drive (V)."""
    w: np.ndarray
    """Recorded displacement (recording units)."""
    baseline: np.ndarray
    """The baseline's prediction of w."""
    extended: np.ndarray
    """The final model's prediction of w (all named causes)."""
    recording: np.ndarray
    """Index of the recording the sample comes from."""
    segment: np.ndarray
    """Index of the contiguous test block it lies in."""
    sample: np.ndarray | None = None
    """Its index within its recording (the held-out samples leave out those w was not measured at: a
    ``quality`` column's 0 inside the record, `DiagnoseSettings.bridge_glitches`)."""


@dataclasses.dataclass
class Candidate:
    """One effect's extended fit and the evidence about it (``to_dict()``: its entry in ``report.json``).

    The step that weighs it against the model it extends sets `gain`, `delta_bic`,
    `eligible` and `reasons`; `evaluate_candidate` sets the rest.
    """

    name: str
    """The effect it adds ("none": the model it extends, refitted)."""
    parameters: dict
    """Fitted value of each parameter of the simulation and its named effects, by name."""
    derived: dict
    """The effect's size in physical terms (`AbstractEffect.derived`), by name."""
    train_rss: float
    """Residual sum of squares on the training part."""
    n_parameters: int
    """Free parameters, for the BIC."""
    bic: float
    """BIC on the training part."""
    heldout: HeldoutMetrics
    """Its errors on the held-out part."""
    ljung_box: dict
    """Ljung–Box whiteness of the held-out residual (`residual_tests.ljung_box`, as in ``report.json``)."""
    gain: float = float("nan")
    """Held-out NMSE of the model it extends over its own."""
    delta_bic: float = float("nan")
    """Its BIC minus that of the model it extends."""
    material: bool = False
    """Whether the fitted effect is as large as `DiagnoseSettings.materiality` asks."""
    eligible: bool = False
    """Whether it passes every rule of the step that weighs it."""
    materiality: str = ""
    """The effect's size against its materiality threshold, in words."""
    reasons: list = dataclasses.field(default_factory=list)
    """Why it is not eligible, or how it was refitted, in words."""
    theta: np.ndarray | None = None
    """Its end point in the search's θ layout."""
    active: np.ndarray | None = None
    """Its effects' switches."""
    raced: bool = True
    """False where its effect left the race after `DiagnoseSettings.start_steps` LM steps, trailing the
    `DiagnoseSettings.racing_effects` leading effects: its numbers are those of that short fit."""
    validation_loss: float = float("nan")
    """½ mean r² on the validation part (the lane's)."""
    heldout_residual: np.ndarray | None = None
    """w − ŵ on the held-out part, in the recording's units (for comparing rivals; not in ``report.json``)."""

    @property
    def refused_for_size(self) -> bool:
        """Whether every rule of its step passed but materiality (`Diagnosis.too_small`)."""
        return bool(self.reasons) and all(r.startswith("not material") for r in self.reasons)

    def to_dict(self) -> dict:
        return {
            "name": self.name,
            "heldout_nmse": self.heldout.nmse,
            "heldout_fitting": self.heldout.fitting,
            "gain": self.gain,
            "criterion": {"bic": self.bic, "delta_bic": self.delta_bic},
            "ljung_box": self.ljung_box,
            "parameters": self.parameters,
            "derived": self.derived,
            "material": self.material,
            "materiality": self.materiality,
            "eligible": self.eligible,
            "reasons": self.reasons,
            "raced": self.raced,
        }


@dataclasses.dataclass
class Diagnosis:
    """What `diagnose` found; `to_dict()` is ``report.json``."""

    cause: str
    baseline: Candidate
    extended: Candidate
    candidates: list[Candidate]
    uncertainties: dict[str, ParameterUncertainty]
    evidence: dict
    hybrid: dict | None
    settings: DiagnoseSettings
    recordings: list
    seconds: float
    #: Held-out signals of the baseline and the final model (`HeldoutSignals`).
    heldout: HeldoutSignals
    #: Every candidate lane of every step (not in ``report.json``).
    lanes: list[Lane] = dataclasses.field(default_factory=list)
    #: Each step of the stepwise search (`hybrid.discovery._step.Step`): the effect it
    #: named (``cause``, or None), the Candidate it extended and those weighed against it.
    steps: list[Step] = dataclasses.field(default_factory=list)
    #: The measurement noise of w, from the recordings alone (`NoiseFloor`).
    noise_floor: NoiseFloor | None = None
    #: None when the final model reaches the noise floor, else how much of its
    #: held-out error lies above it and where (see `hybrid.discovery._unexplained`).
    unexplained: dict | None = None
    #: The effects the search weighed (`AbstractEffect` instances, in the stack's order).
    effects: tuple = ()
    #: Where the search looked (`searched_places`): per place, its effects, or why none was searched.
    places: dict = dataclasses.field(default_factory=dict)
    #: Parameters this recording does not pin (standard error infinite or above the value): why, by name.
    not_pinned: dict = dataclasses.field(default_factory=dict)
    #: Each step whose named cause this recording cannot tell from other eligible effects, or that
    #: predict alike to within the noise (`hybrid.discovery._ambiguity`): the rivals, their gains, the
    #: tests and why, where it shows; and
    #: the last step, when it named nothing and an effect may still be missing (``open``: a remainder
    #: above the noise floor, or at the floor a candidate's significant gain; ``evidence`` says which).
    ambiguous: list = dataclasses.field(default_factory=list)
    #: The fitted models (`hybrid.Model`, simulation + gain and offset in the recording's units):
    #: ``"baseline"`` (the simulation and the frame timing) and ``"extended"`` (with every named
    #: cause); `write_report` saves them as ``baseline.eqx`` and ``extended.eqx``.
    models: dict = dataclasses.field(default_factory=dict)
    #: Every parameter's unit, from the units of the signals it acts on (the recordings' drive and w,
    #: the simulation's output, a state's): fitted or fixed.
    units: dict = dataclasses.field(default_factory=dict)
    #: The units of the recorded signals: ``{"w": ..., "v_in": ...}`` as the recordings declare them
    #: (mm and V where they do not; the paper's where several disagree). Labels and sentences use them.
    signal_units: dict = dataclasses.field(default_factory=lambda: dict(PAPER_UNITS))
    #: Named causes the final model did not need once each was weighed as if named last
    #: (`hybrid.discovery._redundant`): name, the step that named it, the gain with it over
    #: without it, the rules that gain failed. Not among `causes`.
    dropped: list = dataclasses.field(default_factory=list)
    #: What about the search should not be taken at face value, one sentence each: a plug-in effect
    #: whose predictions were not finite over part of its parameters' range (`nonfinite_warnings`), the
    #: final model's fit (`model_warnings`).
    warnings: list = dataclasses.field(default_factory=list)
    #: w's glitches `diagnose` bridged by straight lines before any fit (`DiagnoseSettings.bridge_glitches`):
    #: per recording that had any, its name and the runs, each [first, last] sample.
    glitches_bridged: list = dataclasses.field(default_factory=list)
    #: Each effect of the final model's derived quantities (`AbstractEffect.derived`), by name: what
    #: `causes` gives beside the final model's parameters (a step's own values are its candidates').
    final_derived: dict = dataclasses.field(default_factory=dict)

    def _effect(self, name: str):
        """The searched effect `name` (the built-in classes where none are recorded), or None."""
        return next((e for e in self.effects or tuple(EFFECTS.values()) if e.name == name), None)

    def effect_parameters(self, name: str) -> tuple[str, ...]:
        """The parameter names of the searched effect `name` (none for an unknown name)."""
        effect = self._effect(name)
        return () if effect is None else tuple(effect.constraints)

    def effect_reading(self, name: str, values: dict[str, float]) -> str:
        """What the searched effect `name` fitted to `values` means for the system (`AbstractEffect.reading`)."""
        effect = self._effect(name)
        if effect is None or isinstance(effect, type):
            return ""
        return effect.reading(values, self.signal_units.get("w", ""))

    @property
    def gain(self) -> float:
        """Held-out NMSE of the baseline over that of the final model (all causes)."""
        return self.baseline.heldout.nmse / self.extended.heldout.nmse

    @property
    def causes(self) -> list[dict]:
        """The named causes in the order found: name, parameters (of that effect), incremental held-out gain."""
        out = []
        gone = {d["name"] for d in self.dropped}
        for k, step in enumerate(self.steps, 1):
            if step.cause is None or step.cause in gone:
                continue
            chosen = next(c for c in step.candidates if c.name == step.cause)
            # its values in the final model (the one saved and whose standard errors are given)
            own = {
                k: v for k, v in self.extended.parameters.items() if k in self.effect_parameters(chosen.name)
            }
            joint = (
                {"named_jointly_with": step.joint_with, "joint": chosen.reasons[0]} if step.joint_with else {}
            )
            # the reading sees its derived quantities on the recording too (where the output went)
            derived = self.final_derived.get(chosen.name, chosen.derived)
            sizes = {k: float(v) for k, v in derived.items() if isinstance(v, int | float)}
            timing = {
                k: float(v) for k, v in self.extended.parameters.items() if k in FrameTiming.constraints
            }
            values = {**sizes, **timing, **{k: float(v) for k, v in own.items()}}
            reading = self.effect_reading(chosen.name, values)
            effect = self._effect(chosen.name)
            points_at = (
                effect.points_at(values) if effect is not None and not isinstance(effect, type) else None
            )
            out.append(
                {
                    "name": chosen.name,
                    "place": effect.place if effect is not None else None,
                    "step": k,
                    **joint,
                    "incremental_gain": chosen.gain,
                    "delta_bic": chosen.delta_bic,
                    **({"reading": reading} if reading else {}),
                    **({"points_at": points_at} if points_at else {}),
                    "derived": derived,
                    **({"derived_units": units} if (units := self._derived_units(chosen.name)) else {}),
                    **(
                        {"as_recorded": recorded, "as_recorded_unit": self.signal_units.get("w", "")}
                        if (recorded := self._as_recorded(chosen.name, derived))
                        else {}
                    ),
                    "parameters": {
                        k: {
                            "value": v,
                            "std_error": _std_error(self.uncertainties.get(k)),
                            "unit": self._unit(k),
                            **self._pinning(k),
                            **_optimum(self.uncertainties.get(k)),
                        }
                        for k, v in own.items()
                    },
                }
            )
        return out

    @property
    def too_small(self) -> list[dict]:
        """Candidates that passed every rule but their size, not named: name, step, gain, why, thresholds.

        Materiality is a share of the signal's range (or of the drive): on a
        recording whose range dwarfs its noise (a piezo stage's 100 µm beside a
        0.03 µm gauge) an effect under it can still gain many times held out.
        Not a cause, but the report says so rather than pointing at a weaker
        rival; `DiagnoseSettings.materiality` (``--materiality``) counts it. For
        each effect never named, as the latest step that weighed it found it:
        one that a later step weighed on top of a later cause and refused for
        more than its size is not listed (a probe's backlash, 6.22× at step 1,
        beside the stiffness named there, 0.99× at step 2: "set play_percent_of_range
        to admit it" offered a cause the final model leaves nothing to).
        Largest gain first.
        """
        named = {c["name"] for c in self.causes}
        by_name: dict[str, dict] = {}
        for k, step in enumerate(self.steps, 1):
            for c in step.candidates:
                if c.name in named:
                    continue
                effect = self._effect(c.name)
                # not this effect at all (`unlike`: no threshold should admit it), or refused for more than
                # its size: weighed again on top of a later cause, what an earlier step found is gone
                if unlike([effect] if effect is not None else [], c) or not (
                    c.refused_for_size and c.gain >= self.settings.min_gain
                ):
                    by_name.pop(c.name, None)
                    continue
                by_name[c.name] = {
                    "name": c.name,
                    "step": k,
                    "gain": c.gain,
                    "materiality": c.materiality,
                    "thresholds": {} if effect is None else thresholds_of(effect, self.settings.materiality),
                }
        return sorted(by_name.values(), key=lambda d: -d["gain"])

    @property
    def verdict(self) -> str:
        """One sentence that states the answer: the causes, the gain, and what remains above the noise."""
        from ._verdict import verdict

        return verdict(self)

    def _derived_units(self, name: str) -> dict[str, str]:
        """The units of effect `name`'s derived quantities (`AbstractEffect.derived_units`), as the final
        model's stack fills them (in the recordings' drive unit, which `diagnose` builds it with)."""
        table = getattr(getattr(self.models.get("extended"), "simulation", None), "derived_units", None)
        return dict(table.get(name, {})) if isinstance(table, dict) else {}

    def _as_recorded(self, name: str, derived: dict) -> dict[str, float]:
        """Output-side effect `name`'s `levels` among `derived`, as recorded: through the final model's
        linear readout (w = gain·y + offset), in w's unit. Empty for a drive-side or inside effect
        (its levels are in a recorded signal's or a state's unit already) and for a readout
        without a gain and an offset (a network)."""
        effect = self._effect(name)
        model = self.models.get("extended")
        if effect is None or effect.place != "output" or not effect.levels or model is None:
            return {}
        readout = model.readout.parameters()
        if "gain" not in readout or "offset" not in readout:
            return {}
        gain, offset = float(readout["gain"]), float(readout["offset"])
        return {
            k: offset + sign * gain * float(derived[k])
            for k, sign in effect.levels.items()
            if isinstance(derived.get(k), int | float) and math.isfinite(derived[k])
        }

    def _unit(self, name: str) -> str:
        return self.units.get(name) or _unit(self.uncertainties.get(name))

    def _pinning(self, name: str) -> dict:
        """``pinned`` (and, when false, ``not_pinned``: why) of a parameter with a standard error."""
        if name not in self.uncertainties:
            return {}
        if name in self.not_pinned:
            return {"pinned": False, "not_pinned": self.not_pinned[name]}
        return {"pinned": True}

    def to_dict(self) -> dict:
        return {
            "schema": REPORT_SCHEMA,
            "units": dict(self.signal_units),
            "verdict": self.verdict,
            "cause": self.cause,
            "causes": self.causes,
            "noise_floor": self.noise_floor.to_dict() if self.noise_floor is not None else None,
            "unexplained": self.unexplained,
            "ambiguous": self.ambiguous,
            "ambiguity_test": AMBIGUITY_TEST,
            "dropped": self.dropped,
            "too_small": self.too_small,
            "warnings": self.warnings,
            "glitches_bridged": self.glitches_bridged,
            "steps": [
                {
                    "cause": step.cause,
                    "extends": step.current.name,
                    "candidates": [c.to_dict() for c in step.candidates],
                }
                for step in self.steps[1:]
            ],
            "baseline": _heldout_summary(self.baseline.heldout),
            "extended": _heldout_summary(self.extended.heldout),
            "nmse_definition": "held-out MSE / var(w) (nmse_eq18: the paper's Eq 18, each signal by its max |.|)",
            "gain": self.gain,
            "parameters": {
                k: {
                    "value": v,
                    "std_error": _std_error(self.uncertainties.get(k)),
                    "std_error_given_network": _std_error_given_network(self.uncertainties.get(k)),
                    **_optimum(self.uncertainties.get(k)),
                    "unit": self._unit(k),
                    **self._pinning(k),
                }
                for k, v in self.extended.parameters.items()
            },
            "effect_derived": self.extended.derived,
            "effects": [
                {"name": e.name, "place": e.place, "parameters": list(e.constraints)} for e in self.effects
            ],
            "places": self.places,
            "candidates": [c.to_dict() for c in self.candidates],
            "baseline_fit": self.baseline.to_dict(),
            "evidence": self.evidence,
            "hybrid": self.hybrid,
            "settings": dataclasses.asdict(self.settings),
            "recordings": self.recordings,
            "seconds": self.seconds,
            "split": _split_description(self.settings),
        }


def _heldout_summary(heldout: HeldoutMetrics) -> dict:
    """``report.json``'s ``baseline`` and ``extended``: the held-out metrics it shows, in its order."""
    return {
        "nmse": heldout.nmse,
        "fitting": heldout.fitting,
        "nmse_eq18": heldout.nmse_eq18,
        "nmse_target": heldout.nmse_target,
    }


def _std_error(u: ParameterUncertainty | None) -> float | None:
    return u.std_error if u is not None else None


def _std_error_given_network(u: ParameterUncertainty | None) -> float | None:
    return u.std_error_given_network if u is not None else None


def _optimum(u: ParameterUncertainty | None) -> dict:
    """``to_training_optimum`` and ``at_training_optimum`` of a parameter with a standard error."""
    if u is None or u.to_optimum is None or not math.isfinite(u.to_optimum):
        return {}  # unidentifiable, or the optimum not found: nothing said
    return {"to_training_optimum": u.to_optimum, "at_training_optimum": not u.held_off_optimum}


def _unit(u: ParameterUncertainty | None) -> str:
    return u.unit if u is not None else ""


def _split_description(settings: DiagnoseSettings) -> str:
    train, validation, test = (f"{x:.0%}" for x in settings.split)
    blocks = settings.split_blocks
    if blocks == 1:
        return f"train first {train}, validation next {validation}, held-out (test) last {test} of each recording"
    why = ""
    if settings.held_out_limits and settings.extremes_held_out is not None:
        runs = "where a recording sits flat at its largest or smallest value"
        if not settings.extremes_held_out:
            why = (
                f" (no count up to {MAX_BLOCKS_FACTOR * settings.blocks} has held-out parts that see {runs}: "
                "a limit there is tested on training data alone)"
            )
        elif blocks != settings.blocks:
            why = f" ({settings.blocks} asked: {blocks} are the fewest whose held-out parts see {runs})"
    return (
        f"each recording in {blocks} equal blocks{why}; in each block train first {train}, validation next "
        f"{validation}, held-out (test) last {test}"
    )
