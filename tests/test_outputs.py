"""Issue 20: the command line never loses data and refuses bad output paths before it computes.

Outputs never overwrite an input, every file is written atomically (a full disk
leaves the previous file byte for byte), output paths are checked before any
work, one process writes an output at a time, `rc` reads drives like every other
command, and every size argument is bounded. Each test is a small, fast case.
"""

import errno
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from hybrid import InputError, Recording, make_model, save_model
from hybrid.cli import main


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


def assert_one_line_error(code, err, *phrases):
    assert code == 2, err
    # a heartbeat ("hybrid fit: still working: ...") is progress on a busy machine, not part of the error
    lines = [line for line in err.splitlines() if line.strip() and ": still working: " not in line]
    assert len(lines) == 1, err
    assert lines[0].startswith("hybrid: error: ") and "Traceback" not in err
    for phrase in phrases:
        assert phrase in lines[0], lines[0]


def snapshot(folder: Path) -> dict:
    """Every file under `folder` with its bytes (temporaries and locks included)."""
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def leftovers(folder: Path) -> list:
    return [p.name for p in folder.rglob("*") if ".tmp" in p.name or p.name.endswith(".lock")]


@pytest.fixture(scope="module")
def recording_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("outputs") / "source" / "rec.csv"
    path.parent.mkdir()
    Recording.from_arrays(
        v_in=np.sin(np.arange(300) / 9.0), w=np.cos(np.arange(300) / 7.0), rate=30.0, name="rec"
    ).save(path)
    return path


@pytest.fixture
def rec(recording_file, tmp_path, monkeypatch):
    """A fresh copy of a 10 s recording (+ sidecar) in the test's own folder, which is the cwd."""
    monkeypatch.chdir(tmp_path)
    for p in (recording_file, Path(f"{recording_file}.json")):
        (tmp_path / p.name).write_bytes(p.read_bytes())
    return tmp_path / "rec.csv"


def fast_network(monkeypatch):
    """V_o = V_i: these tests are about files, not the network (tests/test_cli.py checks V_o)."""
    import hybrid.physics._rc_network

    monkeypatch.setattr(hybrid.physics._rc_network.RCNetwork, "simulate", lambda self, v_in, dt: v_in)


def refuse_to_compute(monkeypatch):
    """Make the expensive step fail loudly: a check must refuse before it is reached."""
    import hybrid.core._fit
    import hybrid.discovery._diagnose
    import hybrid.ipmc._sensitivity_study
    import hybrid.ipmc._table2
    import hybrid.ipmc._virtual_ipmc

    def boom(*args, **kwargs):
        raise AssertionError("computed before checking the outputs")

    monkeypatch.setattr(hybrid.core._fit, "fit", boom)
    monkeypatch.setattr(hybrid.ipmc._defaults, "diagnose", boom)  # what the CLI calls
    monkeypatch.setattr(hybrid.ipmc._virtual_ipmc, "virtual_recording", boom)
    monkeypatch.setattr(hybrid.ipmc._table2, "reproduce_table2", boom)
    monkeypatch.setattr(hybrid.ipmc._sensitivity_study, "run_sensitivity_study", boom)


# --------------------------------------------------------------------------- 1. never write over an input


@pytest.mark.parametrize(
    "argv, phrase",
    [
        (["fit", "REC", "--out", "REC"], "is the input"),
        (["fit", "REC", "--out", "x.eqx", "--json", "REC.json"], "sidecar of the input"),
        (["fit", "REC", "--out", "REC.eqx", "--json", "REC.eqx.json"], "both write"),
        (["rc", "REC", "--out", "REC"], "is the input"),
        (["rc", "REC", "--out", "./sub/../REC"], "is the input"),
        (["rc", "REC", "--out", "REC.json"], "sidecar of the input"),
    ],
)
def test_an_output_never_overwrites_an_input(argv, phrase, rec, capsys, monkeypatch):
    refuse_to_compute(monkeypatch)
    (rec.parent / "sub").mkdir()
    before = snapshot(rec.parent)
    code, _, err = run([str(rec.name) if a == "REC" else a.replace("REC", rec.name) for a in argv], capsys)
    assert_one_line_error(code, err, phrase, "choose another" if "both" not in phrase else "different names")
    assert snapshot(rec.parent) == before


def test_an_output_linked_to_an_input_is_refused(rec, capsys):
    (rec.parent / "soft.csv").symlink_to(rec)
    os.link(rec, rec.parent / "hard.csv")
    before = snapshot(rec.parent)
    for name in ("soft.csv", "hard.csv"):
        code, _, err = run(["rc", rec, "--out", rec.parent / name], capsys)
        assert_one_line_error(code, err, "is the input")
    assert snapshot(rec.parent) == before


# --------------------------------------------------------------------------- 2. atomic writes


def full_disk(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def test_staged_write_on_a_full_disk_changes_nothing(tmp_path, monkeypatch):
    from hybrid.util import _atomic

    target = tmp_path / "old.txt"
    target.write_text("the previous, good content\n")
    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(InputError, match="No space left on device; nothing was changed at"):
        _atomic.write_text(target, "new content that does not fit")
    assert target.read_text() == "the previous, good content\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["old.txt"]


def test_staged_pair_is_replaced_together_or_not_at_all(tmp_path):
    from hybrid.util import _atomic

    a, b = tmp_path / "m.eqx", tmp_path / "m.eqx.json"
    a.write_text("A0")
    b.write_text("B0")
    with pytest.raises(RuntimeError):
        with _atomic.staged(a, b) as (ta, tb):
            ta.write_text("A1")
            raise RuntimeError("the description could not be built")
    assert (a.read_text(), b.read_text()) == ("A0", "B0") and len(list(tmp_path.iterdir())) == 2
    with _atomic.staged(a, b) as (ta, tb):
        ta.write_text("A1")
        tb.write_text("B1")
    assert (a.read_text(), b.read_text()) == ("A1", "B1") and len(list(tmp_path.iterdir())) == 2
    mask = os.umask(0o022)
    os.umask(mask)
    _atomic.write_text(tmp_path / "new.txt", "x")
    assert (tmp_path / "new.txt").stat().st_mode & 0o777 == 0o666 & ~mask  # not mkstemp's 0600


def test_save_model_on_a_full_disk_keeps_the_previous_model(tmp_path, monkeypatch):
    import equinox as eqx

    path = tmp_path / "strip.eqx"
    save_model(path, make_model("physics"), extra={"good": True})
    before = snapshot(tmp_path)
    serialise = eqx.tree_serialise_leaves

    def half_then_full(handle, model, *args, **kwargs):
        handle.write(b"\x00" * 10)  # part of the leaves, then the disk fills up
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(eqx, "tree_serialise_leaves", half_then_full)
    with pytest.raises(InputError, match=r"strip\.eqx.*No space left on device"):
        save_model(path, make_model("physics", simulation=None), extra={"good": False})
    monkeypatch.setattr(eqx, "tree_serialise_leaves", serialise)
    assert snapshot(tmp_path) == before  # the model, its .json, and no temporary


def test_simulate_on_a_full_disk_keeps_the_previous_recording(rec, capsys, monkeypatch):
    before = snapshot(rec.parent)

    def half_then_full(fname, *args, **kwargs):
        Path(fname).write_text("t,v_in,w\n0,0,0\n")  # a truncated but loadable CSV
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(np, "savetxt", half_then_full)
    code, _, err = run(["simulate", "--drive", "prbs", "--duration", "10", "--out", rec], capsys)
    assert_one_line_error(code, err, "No space left on device", "nothing was changed at")
    assert snapshot(rec.parent) == before


def test_rc_on_a_full_disk_keeps_the_previous_output(rec, capsys, monkeypatch):
    fast_network(monkeypatch)
    out = rec.parent / "vo.csv"
    out.write_text("previous\n")
    before = snapshot(rec.parent)
    monkeypatch.setattr(os, "fsync", full_disk)
    code, _, err = run(["rc", rec, "--stages", "3", "--out", out], capsys)
    assert_one_line_error(code, err, "No space left on device")
    assert snapshot(rec.parent) == before


def test_figures_are_written_atomically(tmp_path, monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from hybrid.util._figures import save_png

    path = tmp_path / "fig.png"
    path.write_bytes(b"old png")
    fig = plt.figure(figsize=(1, 1))
    monkeypatch.setattr(os, "fsync", full_disk)
    with pytest.raises(InputError, match="No space left"):
        save_png(fig, path, dpi=10)
    assert path.read_bytes() == b"old png" and len(list(tmp_path.iterdir())) == 1
    monkeypatch.undo()
    fig = plt.figure(figsize=(1, 1))
    save_png(fig, path, dpi=10)
    assert path.read_bytes().startswith(b"\x89PNG")


def test_table2_and_sensitivity_write_through_the_atomic_helper():
    # Their every write goes through hybrid.util._atomic (no bare write_text/savefig left).
    import inspect

    from hybrid.ipmc import _sensitivity_study, _table2
    from hybrid.util import _figures

    for module in (_table2, _sensitivity_study, _figures):
        source = inspect.getsource(module)
        assert (
            ".write_text(" not in source and "savefig(out_dir" not in source and "savefig(path" not in source
        )


# --------------------------------------------------------------------------- 3. outputs checked before computing


@pytest.mark.parametrize(
    "argv, phrase",
    [
        (["fit", "REC", "--out", "out/strip1"], "suffix"),
        (["fit", "REC", "--out", "folder"], "is a folder"),
        (["fit", "REC", "--out", "afile/strip.eqx"], "is a file, not a folder"),
        (["fit", "REC", "--json", "report.txt"], "suffix"),
        (["rc", "REC", "--out", "vo.txt"], "suffix"),
        (["rc", "REC", "--out", "folder"], "is a folder"),
        (["simulate", "--drive", "sine", "--duration", "5", "--out", "rec.xlsx"], "suffix"),
        (["diagnose", "REC", "--out", "afile"], "is a file, not a folder"),
        (["diagnose", "REC", "--out", "afile/diag"], "is a file, not a folder"),
        (["sensitivity", "--out", "afile"], "is a file, not a folder"),
        (["table2", "--out-dir", "afile"], "is a file, not a folder"),
    ],
)
def test_bad_output_paths_are_refused_before_any_work(argv, phrase, rec, capsys, monkeypatch):
    refuse_to_compute(monkeypatch)
    (rec.parent / "folder").mkdir()
    (rec.parent / "afile").write_text("not a folder")
    before = snapshot(rec.parent)
    code, _, err = run([rec if a == "REC" else a for a in argv], capsys)
    assert_one_line_error(code, err, phrase)
    assert snapshot(rec.parent) == before and not (rec.parent / "out").exists()


def test_output_folders_are_created_and_checked_writable(tmp_path):
    from hybrid.util._outputs import OutputFile, prepare_outputs

    target = tmp_path / "new" / "deeper" / "m.eqx"
    with prepare_outputs([OutputFile(target, "--out", (".eqx",))]):
        assert target.parent.is_dir() and Path(f"{target}.lock").read_text().strip() == str(os.getpid())
    assert not Path(f"{target}.lock").exists() and list(target.parent.iterdir()) == []


def test_a_failed_command_leaves_no_folder_or_lock_behind(rec, capsys, monkeypatch):
    import hybrid.core._fit

    def bad_fit(*args, **kwargs):
        raise InputError("the fit failed")

    monkeypatch.setattr(hybrid.core._fit, "fit", bad_fit)
    before = snapshot(rec.parent)
    code, _, err = run(["fit", rec, "--model", "physics", "--out", "new/deeper/m.eqx", "--quiet"], capsys)
    assert_one_line_error(code, err, "the fit failed")
    assert not (rec.parent / "new").exists() and snapshot(rec.parent) == before


def test_a_users_own_files_in_an_output_folder_are_never_replaced(rec, capsys, monkeypatch):
    """A probe's --out folder held its own report.md and baseline.eqx: diagnose replaced both without a word."""
    refuse_to_compute(monkeypatch)
    diag = rec.parent / "diag"
    diag.mkdir()
    (diag / "report.md").write_text("# my own notes\n")
    (diag / "baseline.eqx").write_bytes(b"my model")
    before = snapshot(diag)
    code, _, err = run(["diagnose", rec, "--out", "diag"], capsys)
    assert_one_line_error(code, err, "already holds report.md, baseline.eqx", "no hybrid command wrote")
    assert snapshot(diag) == before


def test_an_output_folder_lists_what_it_wrote_and_a_rerun_replaces_only_that(tmp_path):
    from hybrid.util._outputs import MANIFEST, OutputFolder, prepare_outputs

    folder = OutputFolder(tmp_path / "out", "--out", ("a.txt", "b.txt"))
    with prepare_outputs([folder]):
        (folder.path / "a.txt").write_text("first run")
    assert json.loads((folder.path / MANIFEST).read_text()) == {"files": ["a.txt"]}
    with prepare_outputs([folder]):  # its own a.txt: a rerun may replace it
        (folder.path / "a.txt").write_text("second run")
    (folder.path / "b.txt").write_text("the user's")  # a name the command writes, put there by hand
    with pytest.raises(InputError, match=r"already holds b\.txt, which no hybrid command wrote"):
        prepare_outputs([folder])
    (folder.path / "b.txt").unlink()
    with pytest.raises(RuntimeError), prepare_outputs([folder]):  # a failed run: nothing is listed
        (folder.path / "b.txt").write_text("half")
        raise RuntimeError("the command failed")
    assert json.loads((folder.path / MANIFEST).read_text()) == {"files": ["a.txt"]}


def test_a_command_runs_again_into_its_own_folder(rec, capsys):
    argv = ["sensitivity", rec, "--physics", "lti:1", "--out", "sens"]
    assert run(argv, capsys)[0] == 0
    (rec.parent / "sens" / "notes.txt").write_text("mine")  # not a name the command writes
    code, _, err = run(argv, capsys)
    assert code == 0, err
    assert (rec.parent / "sens" / "notes.txt").read_text() == "mine"


# --------------------------------------------------------------------------- 4. one writer per output


def test_a_locked_output_is_refused(rec, capsys):
    out = rec.parent / "new.csv"
    lock = Path(f"{out}.lock")
    lock.write_text(f"{os.getpid()}\n")  # held by a live process (this one)
    code, _, err = run(["simulate", "--drive", "sine", "--duration", "2", "--out", out], capsys)
    assert_one_line_error(code, err, f"another hybrid process (pid {os.getpid()}) is writing")
    assert not out.exists() and lock.read_text().strip() == str(os.getpid())


def test_a_locked_output_folder_is_refused(rec, capsys, monkeypatch):
    refuse_to_compute(monkeypatch)
    (rec.parent / "diag").mkdir()
    (rec.parent / "diag" / ".hybrid.lock").write_text(f"{os.getpid()}\n")
    code, _, err = run(["diagnose", rec, "--out", "diag"], capsys)
    assert_one_line_error(code, err, "another hybrid process")


def test_a_stale_lock_is_taken_over_and_released(rec, capsys):
    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    out = rec.parent / "new.csv"
    Path(f"{out}.lock").write_text(f"{dead.pid}\n")
    code, _, err = run(["simulate", "--drive", "sine", "--duration", "2", "--out", out], capsys)
    assert code == 0, err
    assert Recording.load(out).n == 60 and not Path(f"{out}.lock").exists()


def test_the_lock_is_released_when_the_command_fails(rec, capsys, monkeypatch):
    out = rec.parent / "new.csv"
    monkeypatch.setattr(os, "fsync", full_disk)
    code, _, err = run(["simulate", "--drive", "sine", "--duration", "2", "--out", out], capsys)
    assert code == 2 and leftovers(rec.parent) == [] and not out.exists()


# --------------------------------------------------------------------------- 5. rc reads drives like fit


@pytest.mark.parametrize(
    "name, text",
    [
        ("comment.csv", "# a comment\nt,v_in,w\n0,1,2\n0.1,x,2\n0.2,1,2\n"),
        ("bom.csv", "\ufefft,v_in,w\n0,1,2\n0.1,1,2\n0.2,oops,2\n"),
        ("folder.csv", None),
        ("gap.csv", "t,v_in,w\n0,1,2\n0.1,1,2\n0.5,1,2\n"),
    ],
)
def test_rc_and_fit_give_the_same_message_for_a_bad_file(name, text, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    path = tmp_path / name
    if text is None:
        path.mkdir()
    else:
        path.write_text(text, encoding="utf-8")
    code_rc, _, err_rc = run(["rc", path, "--out", "vo.csv"], capsys)
    code_fit, _, err_fit = run(["fit", path, "--quiet"], capsys)
    assert_one_line_error(code_rc, err_rc)
    assert err_rc == err_fit


def test_rc_reads_a_bom_drive_without_w(tmp_path, capsys, monkeypatch):
    fast_network(monkeypatch)
    drive = tmp_path / "drive.csv"
    t = np.arange(300) / 30.0
    drive.write_text(
        "\ufeff# from Excel\nt,v_in\n" + "".join(f"{a:.17g},{b:.17g}\n" for a, b in zip(t, np.sin(t))),
        encoding="utf-8",
    )
    code, _, err = run(["rc", drive, "--stages", "3", "--out", tmp_path / "vo.csv"], capsys)
    assert code == 0, err
    data = np.genfromtxt(tmp_path / "vo.csv", delimiter=",", names=True)
    assert data.dtype.names == ("t", "v_in", "v_o") and len(data) == 300


def test_rc_has_no_csv_reader_of_its_own():
    import hybrid.cli

    assert not hasattr(hybrid.cli, "_read_drive")


def test_recording_load_without_w(tmp_path):
    path = tmp_path / "drive.csv"
    path.write_text("t,v_in\n0,1\n1,2\n2,3\n")
    with pytest.raises(InputError, match="w"):
        Recording.load(path)
    drive = Recording.load(path, require_w=False)
    assert np.array_equal(drive.v_in, [1, 2, 3]) and np.array_equal(drive.w, [0, 0, 0])


# --------------------------------------------------------------------------- 6. bounded sizes


@pytest.mark.parametrize(
    "argv, phrase",
    [
        (["rc", "REC", "--stages", "100000", "--out", "y.csv"], "from 1 to 1000"),
        (["rc", "REC", "--stages", "0", "--out", "y.csv"], "from 1 to 1000"),
        (
            ["simulate", "--drive", "prbs", "--duration", "10", "--rate", "1e9", "--out", "x.csv"],
            "at most 100000 Hz",
        ),
        (
            ["simulate", "--drive", "prbs", "--duration", "10", "--rate", "0", "--out", "x.csv"],
            "at least 0.1 Hz",
        ),
        (["simulate", "--drive", "prbs", "--duration", "inf", "--out", "x.csv"], "finite"),
        (["simulate", "--drive", "prbs", "--duration", "0", "--out", "x.csv"], "more than 0 s"),
        (
            ["simulate", "--drive", "prbs", "--duration", "1e6", "--rate", "100", "--out", "x.csv"],
            "limit of 1e+07",
        ),
        (["fit", "REC", "--starts", "0"], "--starts: must be from 1"),
        (["fit", "REC", "--starts", "1e9"], "--starts: expected a whole number"),
        (["fit", "REC", "--max-steps", "-3"], "--max-steps: must be from 0"),  # 0: score a saved model
        (["fit", "REC", "--window", "0"], "--window: must be from 1"),
        (["fit", "REC", "--depth", "100000"], "--depth: must be from 0 to 50"),
        (["fit", "REC", "--width", "0"], "--width: must be from 1 to 1000"),
        (["table2", "--duration", "-5"], "--duration: must be finite"),
        (["table2", "--duration", "1e6"], "limit of 1e+07"),
        (["table2", "--starts", "0"], "--starts"),
        (["sensitivity", "--out", "s", "--sobol", "1000000000"], "--sobol: must be from 0 to 100000"),
        (["sensitivity", "--out", "s", "--stages", "5000"], "--stages: must be from 1 to 1000"),
        (["sensitivity", "--out", "s", "--rate", "1e9"], "--rate"),
        (["sensitivity", "--out", "s", "--duration", "nan"], "--duration: must be finite"),
        (["diagnose", "REC", "--out", "d", "--blocks", "100000"], "--blocks: must be at most 10000"),
        (
            ["diagnose", "REC", "--out", "d", "--max-steps", "1e9"],
            "--max-steps: expected a whole number at most",
        ),
        (
            ["diagnose", "REC", "--out", "d", "--max-steps", "10000000"],
            "--max-steps: must be at most 1000000",
        ),
    ],
)
def test_size_arguments_are_bounded(argv, phrase, rec, capsys, monkeypatch):
    refuse_to_compute(monkeypatch)
    code, _, err = run([rec if a == "REC" else a for a in argv], capsys)
    assert_one_line_error(code, err, phrase)
