"""The race of a step's lanes (`DiagnoseSettings.race_patience`): who goes on, from where, and what is kept."""

from types import SimpleNamespace

import equinox as eqx
import numpy as np
import pytest

import hybrid as hy
from hybrid.core._levenberg_marquardt import LMSettings, LMState
from hybrid.discovery import _step
from hybrid.discovery._diagnosis import DiagnoseSettings
from hybrid.discovery._search import _start_states, lane_tangents, lanes_problem


def _states(theta, best_val, since_best, step):
    """Lane states (numpy rows) at θ with these validation losses, steps since the best and steps."""
    states = _start_states(theta)
    return eqx.tree_at(
        lambda s: (s.best_val, s.since_best, s.step),
        states,
        (np.asarray(best_val, float), np.asarray(since_best, np.int32), np.asarray(step, np.int32)),
    )


def test_each_effects_leaders_go_on_where_they_stopped_and_the_other_lanes_stay_done(monkeypatch):
    settings = DiagnoseSettings()
    lm = LMSettings(max_steps=120)
    labels = ["a", "a", "a", "b", "b", "c", "none", "none"]
    # a: lane 1 leads and lane 2 is within reach of it (1.5 % with the defaults), lane 0 is not;
    # b: lane 3 leads but stopped on its tolerances (done), lane 4 is out of reach;
    # c: lane 5 stopped at max_steps.
    heat_val = [1.02, 1.0, 1.01, 0.5, 0.7, 4.0, np.nan, np.nan]
    since = [10, 10, 10, 2, 10, 10, 0, 0]
    steps = [30, 25, 40, 12, 33, 120, 0, 0]
    calls = []

    def fit_lanes(problem, actives, tangents, starts, lm_settings, patience):
        calls.append(dict(actives=actives, tangents=tangents, starts=starts, patience=patience))
        if len(calls) == 1:  # the heat: every lane, ending 100 away from its start
            thetas = np.asarray(starts)
            return _states(thetas + 100.0, heat_val, since, steps)
        return starts  # what goes on is checked below

    monkeypatch.setattr(_step, "fit_lanes", fit_lanes)
    search = SimpleNamespace(settings=settings, lm=lm, n_val=180, say=lambda message: None, effects=())
    n = len(labels)
    actives = np.arange(n, dtype=float)[:, None] * np.ones((n, 3))
    tangents = np.arange(n, dtype=float)[:, None, None] * np.ones((n, 2, 3))
    lanes = [np.full(4, float(j)) for j in range(n)]

    _step.race(search, object(), actives, tangents, lanes, labels)

    assert [c["patience"] for c in calls] == [settings.race_patience, settings.patience]
    second = calls[1]
    # Every lane is passed back as the heat left it, with the same switches and directions; only a's
    # leaders go on (b's stopped on its tolerances, c's at max_steps, the padding never started).
    assert isinstance(second["starts"], LMState)
    np.testing.assert_array_equal(second["starts"].done, [True, False, False, True, True, True, True, True])
    for j in range(n):
        np.testing.assert_array_equal(second["starts"].theta[j], np.full(4, j + 100.0))
    np.testing.assert_array_equal(second["starts"].since_best, since)
    np.testing.assert_array_equal(second["actives"], actives)
    np.testing.assert_array_equal(second["tangents"], tangents)


def test_race_patience_zero_runs_every_lane_to_the_full_patience(monkeypatch):
    patiences = []

    def fit_lanes(problem, actives, tangents, thetas, lm_settings, patience):
        patiences.append(patience)
        thetas = np.asarray(thetas)
        return _states(thetas, np.ones(thetas.shape[0]), np.full(thetas.shape[0], patience), np.ones(2))

    monkeypatch.setattr(_step, "fit_lanes", fit_lanes)
    settings = DiagnoseSettings(race_patience=0)
    search = SimpleNamespace(
        settings=settings, lm=LMSettings(), n_val=180, say=lambda message: None, effects=()
    )
    _step.race(search, object(), np.ones((2, 3)), np.ones((2, 2, 3)), [np.zeros(4)] * 2, ["a", "a"])
    assert patiences == [settings.patience]


def test_an_effect_that_keeps_one_lane_keeps_its_best_after_the_first_steps(monkeypatch):
    """`AbstractEffect.n_kept`: after `start_steps` LM steps only an effect's best lanes go on."""
    settings = DiagnoseSettings()
    lm = LMSettings(max_steps=120)
    labels = ["a", "a", "a", "b", "b", "c", "none"]
    # a keeps 1 of 3: lane 1 has the least validation loss after the first steps; b keeps every lane
    # (n_kept 0); c keeps 1 and has 1; lane 4 converged within the first steps (done).
    first_val = [3.0, 1.0, 2.0, 5.0, 4.0, 6.0, np.nan]
    first_done = [False, False, False, False, True, False, True]
    calls = []

    def fit_lanes(problem, actives, tangents, starts, lm_settings, patience, steps=None):
        calls.append(dict(starts=starts, patience=patience, steps=steps))
        if len(calls) == 1:
            thetas = np.asarray(starts)
            states = _states(thetas + 1.0, first_val, np.zeros(len(labels)), np.full(len(labels), 6))
            return eqx.tree_at(lambda s: s.done, states, np.asarray(first_done))
        states = starts  # the heat: every lane as it was, none stopped by the patience
        return eqx.tree_at(lambda s: s.since_best, states, np.zeros(len(labels), np.int32))

    monkeypatch.setattr(_step, "fit_lanes", fit_lanes)
    effects = tuple(
        SimpleNamespace(name=name, n_kept=k, place="output") for name, k in (("a", 1), ("b", 0), ("c", 1))
    )
    search = SimpleNamespace(settings=settings, lm=lm, n_val=180, say=lambda message: None, effects=effects)
    n = len(labels)
    lanes = [np.full(4, float(j)) for j in range(n)]
    states, culled = _step.race(search, object(), np.ones((n, 3)), np.ones((n, 2, 3)), lanes, labels)

    assert sorted(culled) == [0, 2]
    assert [(c["patience"], c["steps"]) for c in calls] == [
        (settings.race_patience, settings.start_steps),
        (settings.race_patience, None),
    ]
    heat = calls[1]["starts"]
    assert isinstance(heat, LMState)
    # the culled lanes and the lanes done in the first round stay as they are; the rest go on from there
    np.testing.assert_array_equal(heat.done, [True, False, True, False, True, False, True])
    np.testing.assert_array_equal(heat.theta, np.stack(lanes) + 1.0)

    # A race patience within the first round's steps: every lane's patience stopped it there (done), and
    # the heat leaves them so. Only a's kept lane goes on as a leader, not the two culled beside it.
    def stopped_in_the_first_round(problem, actives, tangents, starts, lm_settings, patience, steps=None):
        calls.append(dict(starts=starts, patience=patience, steps=steps))
        if len(calls) == 1:
            states = _states(np.asarray(starts), [1.0] * 6 + [np.nan], np.full(n, 6), np.full(n, 6))
            return eqx.tree_at(lambda s: s.done, states, np.ones(n, bool))
        return starts

    calls.clear()
    monkeypatch.setattr(_step, "fit_lanes", stopped_in_the_first_round)
    search.settings = DiagnoseSettings(race_patience=3)
    _, culled = _step.race(search, object(), np.ones((n, 3)), np.ones((n, 2, 3)), lanes, labels)
    assert sorted(culled) == [1, 2]  # a's three lanes tie: the first is kept
    np.testing.assert_array_equal(calls[-1]["starts"].done, [False, True, True, False, False, False, True])
    search.settings = settings
    monkeypatch.setattr(_step, "fit_lanes", fit_lanes)
    # no effect with more lanes than it keeps: no first round
    calls.clear()
    search.effects = tuple(SimpleNamespace(name=name, n_kept=0, place="output") for name in "abc")
    _, culled = _step.race(search, object(), np.ones((n, 3)), np.ones((n, 2, 3)), lanes, labels)
    assert culled == [] and [c["steps"] for c in calls] == [None]


def test_only_the_leading_effects_race_on_after_the_first_steps(monkeypatch):
    """`DiagnoseSettings.racing_effects`: beyond it, the effects whose best lane trails after the first round leave.

    Each effect is ranked by its best lane (a's second lane, not its first); a lane the first round
    left non-finite ranks last; a left effect's lanes are culled whole and never go on, and the
    others keep racing, an effect's own `n_kept` cull beside it. An effect inside the dynamics (f)
    races on whatever its first steps gave, and takes none of the field's places.
    """
    labels = ["a", "a", "b", "c", "c", "d", "e", "f", "none"]
    first_val = [9.0, 1.0, 2.0, 3.0, 8.0, 5.0, np.nan, 20.0, np.nan]
    n = len(labels)
    calls, said = [], []

    def fit_lanes(problem, actives, tangents, starts, lm_settings, patience, steps=None):
        calls.append(dict(starts=starts, patience=patience, steps=steps))
        if len(calls) == 1:
            states = _states(np.asarray(starts), first_val, np.zeros(n), np.full(n, 6))
            return eqx.tree_at(lambda s: s.done, states, np.asarray([False] * (n - 1) + [True]))
        return eqx.tree_at(lambda s: s.since_best, starts, np.zeros(n, np.int32))

    def effects(kept: str, inside: str):
        return tuple(
            SimpleNamespace(
                name=name, n_kept=int(name in kept), place="inside" if name in inside else "output"
            )
            for name in "abcdef"
        )

    monkeypatch.setattr(_step, "fit_lanes", fit_lanes)
    search = SimpleNamespace(
        settings=DiagnoseSettings(racing_effects=3),
        lm=LMSettings(max_steps=120),
        n_val=180,
        say=said.append,
        effects=effects(kept="c", inside="f"),
    )
    lanes = [np.full(4, float(j)) for j in range(n)]
    _, culled = _step.race(search, object(), np.ones((n, 3)), np.ones((n, 2, 3)), lanes, labels)
    # a (1.0), b (2.0) and c (3.0) lead; d (5.0) and e (not finite) leave; c's second lane is its n_kept
    # cull; f (20.0, the worst) is inside the dynamics and goes on
    assert sorted(culled) == [4, 5, 6]
    assert [c["steps"] for c in calls] == [DiagnoseSettings().start_steps, None]
    np.testing.assert_array_equal(
        calls[1]["starts"].done, [False, False, False, False, True, True, True, False, True]
    )
    assert any("2 effects left the race" in m and m.endswith("inside the dynamics: d, e") for m in said), said

    # as many effects outside the dynamics as race (f inside counts for none): no effect leaves, and
    # with no n_kept cull either, no first round at all
    for racing in (5, 0):
        calls.clear()
        search.settings = DiagnoseSettings(racing_effects=racing)
        search.effects = effects(kept="", inside="f")
        _, culled = _step.race(search, object(), np.ones((n, 3)), np.ones((n, 2, 3)), lanes, labels)
        assert culled == [] and [c["steps"] for c in calls] == [None]


def test_the_lanes_that_will_run_are_dealt_first_in_their_own_order():
    """`fit_lanes` deals lanes to devices in turn in this order: the running ones spread evenly."""
    from hybrid.discovery._search import _running_first, resume

    theta = np.arange(12.0).reshape(6, 2)
    theta[4] = np.nan  # a padding lane: it restarts from a θ that is not finite and stops at once
    fresh = _start_states(theta)
    assert isinstance(fresh, LMState)
    # fresh starts: every finite lane runs, in its own order; the padding lane goes last
    assert _running_first(fresh, np.ones(6, bool)).tolist() == [0, 1, 2, 3, 5, 4]
    # a resumed race: leaders 1 and 3 (neighbours of a device in turn: 1 and 3 are both odd) first
    heat = eqx.tree_at(lambda s: s.done, fresh, np.ones(6, bool))
    order = _running_first(resume(heat, [1, 3]), np.zeros(6, bool))
    assert order.tolist() == [1, 3, 0, 2, 4, 5]
    # dealt lane k of the order to device k mod 2: the two leaders on different devices
    assert {order.tolist().index(1) % 2, order.tolist().index(3) % 2} == {0, 1}


def test_a_third_step_lane_refits_every_named_effect_where_the_shared_problem_has_directions():
    """`refitted`: all the named effects beside a lane's own where their parameters fit, else the latest.

    The shared problem has directions for LTI(1)'s parameters, the frame timing
    and the two effects with the most parameters (hysteresis 3, saturation or
    resonance 2). A third step's lane whose three effects fit refits all three
    (a later cause can then undo an early name); one that does not holds the
    earliest named effect.
    """
    n = 300
    t = np.arange(n) / 30.0
    recording = hy.Recording(t=t, v_in=np.sin(t), w=np.tanh(np.sin(t)), name="probe")
    simulation = hy.LTI(1)
    settings = DiagnoseSettings()
    effects = ("saturation", "drift", "hysteresis", "resonance")
    problem, n_rows, model = lanes_problem([recording], simulation, settings, effects)
    frozen = frozenset(settings.frozen_for(simulation))
    search = SimpleNamespace(problem=problem, model=model, frozen=frozen)
    search.has_room = lambda effects: _step.Search.has_room(search, effects)  # the search's own test
    present = ("drift", "saturation")
    assert _step.refitted(search, present) == present  # the current model's refit: 1 + 2
    assert _step.refitted(search, present, "resonance") == present  # 1 + 2 + 2: fits
    assert _step.refitted(search, present, "hysteresis") == ("saturation",)  # 1 + 2 + 3: drift held
    assert _step.refitted(search, ("saturation", "hysteresis"), "drift") == ("hysteresis",)
    assert _step.refitted(search, (), "hysteresis") == ()
    # the directions of a lane that fits are all there; more than the rows are refused
    basis = lane_tangents(model, frozen, present + ("resonance",), n_rows)
    assert int(basis.sum()) == n_rows and np.all(basis.sum(axis=1) == 1)  # 1 + 2 + 2 fill the rows
    with pytest.raises(ValueError, match="room for"):
        lane_tangents(model, frozen, present + ("hysteresis",), n_rows)
