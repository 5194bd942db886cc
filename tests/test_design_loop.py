"""`experiments/design_loop.py --merge`: the closed loop's tables count what its rows say (issue 35, item 5).

The rows are written here by hand (no diagnosis runs), so every count in the
table is known: fully named, exactly named, half named and flagged, a draw
that asked no design keeping its result, a draw with an unexplained remainder
and nothing ambiguous recording the rich drive `hybrid design` writes, wrong
names, and a draw rerun in a later file replacing the earlier row.
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _outcome(causes, expected, unexplained=False, open_step=False):
    return {
        "causes": causes,
        "full": set(expected) <= set(causes),
        "exact": set(expected) == set(causes),
        "wrong": sorted(set(causes) - set(expected)),
        "unexplained": unexplained,
        "ambiguous": [{"step": 2, "named": "none", "open": True, "rivals": ["b"]}] if open_step else [],
        "final_over_floor": 1.2,
        "last_step": [
            {
                "name": "b",
                "gain": 1.3,
                "gain_over_bar": 1.2,
                "eligible": False,
                "p_value": 0.01,
                "rms_over_floor": 0.5,
            }
        ],  # fmt: skip
        "seconds": 1.0,
    }


def _row(seed, before, design, control, group="tuning", effect="a+b"):
    expected = ["a", "b"]
    return {
        "effect": effect,
        "seed": seed,
        "group": group,
        "expected": expected,
        "outside": [],
        "before": before,
        "design": design,
        "control": control,
        "seconds": 2.0,
    }


def _design(after):
    return {"step": 2, "rivals": ["none", "b"], "open": True, "seconds": 1.0, "criterion": 20.0,
            "control_criterion": 2.0, "pair": ["none", "b"], "after": after}  # fmt: skip


def _rich(after):
    return {"step": None, "rivals": [], "open": False, "rich_drive": True, "seconds": 1.0, "criterion": None,
            "control_criterion": None, "pair": [], "after": after}  # fmt: skip


def test_the_merged_tables_count_fully_half_and_flagged_draws(tmp_path):
    e = ["a", "b"]
    first = [
        # half named and flagged (open); the designed drive finds both, the control does not
        _row(0, _outcome(["a"], e, open_step=True), _design(_outcome(["a", "b"], e)), _outcome(["a"], e)),
        # fully named with an extra; no design asked: the design column keeps "before"
        _row(1, _outcome(["a", "b", "c"], e), None, _outcome(["a", "b"], e)),
        # half named, not flagged; to be replaced by the second file's rerun
        _row(2, _outcome(["b"], e), None, _outcome([], e)),
        # a wrong name and a remainder unexplained, nothing ambiguous: the rich drive finds a, the control
        # keeps the wrong name
        _row(3, _outcome(["c"], e, unexplained=True), _rich(_outcome(["a"], e)), _outcome(["c"], e)),
    ]
    second = [_row(2, _outcome([], e), None, _outcome(["a", "b"], e))]  # the rerun of seed 2: nothing named
    paths = []
    for k, rows in enumerate((first, second)):
        path = tmp_path / f"part{k}.json"
        path.write_text(json.dumps({"command": f"part {k}", "settings": {}, "rows": rows}))
        paths.append(path)
    out = tmp_path / "loop.json"
    done = subprocess.run(
        [
            sys.executable,
            str(ROOT / "experiments" / "design_loop.py"),
            "--merge",
            *map(str, paths),
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        cwd=tmp_path,
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert [r["seed"] for r in json.loads(out.read_text())["rows"]] == [0, 1, 2, 3]
    text = out.with_suffix(".md").read_text()
    # before: seed 1 full (not exact); after design: seeds 0 and 1 (1 kept) full, seed 0 exact;
    # after control: seeds 1 and 2 full and exact; half named before: seed 0 (flagged) only;
    # a wrong name before: seeds 1 and 3, after design seed 1 (kept), after control seed 3
    assert "| **total** | 4 | 1 (0) | 1 (1) | 2 (1) | 2 (2) | 2 / 1 / 1 |" in text
    assert "| a+b | 0 | a | open |" in text and "| a+b | 1 | both+c |" in text
    assert "| a+b | 2 | ∅ |" in text and "(no design)" in text
    assert "| rich PRBS (unexplained) | a | c |  |  |" in text and "| a+b | 3 | c | unexpl. |" in text
    assert (
        "A design was asked for in 1/4 draws, a rich drive (nothing ambiguous, a remainder unexplained) in 1; "
        "T designed / T control: median 10×." in text
    )
