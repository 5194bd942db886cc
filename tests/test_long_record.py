"""`hybrid diagnose` on a long record says, before it starts, how to make it shorter.

A probe's 200,000 samples at 1 kHz ran for over 11 minutes (it was stopped) without a word on why, where
`hybrid fit` on the same file took 11 s.
"""

from __future__ import annotations

import numpy as np

import hybrid
from hybrid._cli_inputs import LONG_RECORD, long_record_note
from hybrid.cli import main


def _recording(n, rate=1000.0):
    t = np.arange(n) / rate
    return hybrid.Recording(t, np.sign(np.sin(2 * np.pi * t)), np.sin(t))


def test_the_note_counts_every_recording_and_names_the_ways_to_shorten():
    assert long_record_note([_recording(LONG_RECORD - 1)]) is None
    said = long_record_note([_recording(LONG_RECORD // 2), _recording(LONG_RECORD // 2, rate=500.0)])
    assert said.startswith(f"{LONG_RECORD} samples: diagnose fits each candidate effect to every one of them")
    assert "--range A:B" in said and "(here 500 Hz" in said


def test_the_command_line_says_it_before_the_diagnosis(tmp_path, capsys, monkeypatch):
    import hybrid.ipmc._defaults as defaults

    path = _recording(LONG_RECORD).save(tmp_path / "long.csv")

    def stop(*args, **kwargs):  # what follows the note is not this test's
        raise hybrid.InputError("stopped here")

    monkeypatch.setattr(defaults, "diagnose", stop)
    code = main(["diagnose", str(path), "--physics", "lti:1", "--out", str(tmp_path / "d")])
    err = capsys.readouterr().err
    assert code == 2 and "hybrid: note: 50000 samples: diagnose fits each candidate" in err
    assert err.index("hybrid: note:") < err.index("stopped here")
    assert not (tmp_path / "d").exists()
    main(["diagnose", str(path), "--physics", "lti:1", "--quiet", "--out", str(tmp_path / "d")])
    assert "hybrid: note:" not in capsys.readouterr().err
