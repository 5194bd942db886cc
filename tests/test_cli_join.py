"""`--columns` joins a lab's single-column files (one channel per file) into one record.

A logger that writes each channel to its own `.txt` (one number per line, maybe a
header) is fitted with `hybrid fit u.txt y.txt --columns input=u.txt,output=y.txt
--rate 2`; every bad form ends with exit 2 and one line that says how to fix it.
The fit is checked against the time constant the data were made with, so a join
that swapped, shifted or dropped samples would fail.
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from hybrid import InputError
from hybrid.cli import main
from hybrid.data._mapping import load_mapped

LAG = (
    "from typing import ClassVar\n"
    "import jax.numpy as jnp\n"
    "from jax import lax\n"
    "from hybrid import AbstractSimulation, Positive\n"
    "from hybrid import encode\n\n"
    "class Lag(AbstractSimulation):\n"
    "    raw: dict\n"
    "    constraints: ClassVar[dict] = {'tau_s': Positive()}\n"
    "    units: ClassVar[dict] = {'tau_s': 's'}\n"
    "    linear_in_drive: ClassVar[bool] = True\n\n"
    "    def __init__(self, tau_s=2.0):\n"
    "        self.raw = encode({'tau_s': tau_s}, self.constraints, 'Lag')\n\n"
    "    def simulate(self, v_in, dt):\n"
    "        a = jnp.exp(-dt / self.parameters()['tau_s'])\n"
    "        return lax.scan(lambda y, u: (a * y + (1 - a) * u,) * 2, 0.0, jnp.asarray(v_in))[1]\n"
)


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    """u.txt: numbers only; y.txt: a header 'level' then numbers (a first-order lag, tau = 6 samples)."""
    folder = tmp_path_factory.mktemp("logger")
    rng = np.random.default_rng(0)
    u = np.repeat(rng.uniform(-1.0, 1.0, 40), 15)
    y = np.convolve(u, np.exp(-np.arange(30) / 6.0) / 6.0)[: u.size] + 0.001 * rng.normal(size=u.size)
    (folder / "u.txt").write_text("".join(f"{v:.9g}\n" for v in u))
    (folder / "y.txt").write_text("level\n" + "".join(f"{v:.9g}\n" for v in y))
    (folder / "short.txt").write_text("".join(f"{v:.9g}\n" for v in y[:-1]))
    (folder / "both.txt").write_text("".join(f"{a:.9g} {b:.9g}\n" for a, b in zip(u, y)))
    (folder / "lag.py").write_text(LAG)
    return folder, u, y


def test_two_single_column_files_join_and_fit(lab, tmp_path, capsys):
    folder, u, y = lab
    report = tmp_path / "fit.json"
    code, out, err = run(
        [
            "fit",
            folder / "u.txt",
            folder / "y.txt",
            "--columns",
            "input=u.txt,output=y.txt",
            "--rate",
            "2",
            "--physics",
            f"{folder / 'lag.py'}:Lag",
            "--model",
            "physics",
            "--max-steps",
            "20",
            "--quiet",
            "--out",
            tmp_path / "m.eqx",
            "--json",
            report,
        ],
        capsys,
    )
    assert code == 0, err
    # the data's kernel exp(-k/6): tau = 6 samples = 3 s at 2 Hz (the same tolerance as tests/test_cli_mapping.py)
    assert json.loads(report.read_text())["parameters"]["tau_s"] == pytest.approx(3.0, rel=0.2)


def test_the_joined_record_is_the_files_samples(lab):
    """Both forms (FILE and FILE:COLUMN, by name or number) give the same record, sample for sample."""
    folder, u, y = lab
    paths = [folder / "u.txt", folder / "y.txt"]
    joined = load_mapped(paths, columns="input=u.txt,output=y.txt", rate=2)
    np.testing.assert_allclose(joined.v_in, u, rtol=1e-8)
    np.testing.assert_allclose(joined.w, y, rtol=1e-8)
    np.testing.assert_allclose(joined.t, np.arange(u.size) / 2.0)
    assert joined.metadata["mapping"] == {"t": None, "v_in": "u.txt", "w": "y.txt"}
    for columns in ("input=u.txt:0,output=y.txt:level", f"input={paths[0]},output={paths[1]}:0"):
        other = load_mapped(paths, columns=columns, rate=2)
        np.testing.assert_array_equal(other.v_in, joined.v_in)
        np.testing.assert_array_equal(other.w, joined.w)
    one = load_mapped(folder / "both.txt", columns="input=both.txt:0,output=both.txt:1", rate=2)
    np.testing.assert_allclose(one.w, y, rtol=1e-8)
    assert load_mapped(folder / "both.txt", input="0", output="1", rate=2).v_in.tolist() == one.v_in.tolist()


@pytest.mark.parametrize(
    "files, flags, phrases",
    [
        (
            ["u.txt", "short.txt"],
            ["--columns", "input=u.txt,output=short.txt"],
            [
                "the input 'u.txt' has 600",
                "the output 'short.txt' has 599 values",
                "join files of one record",
            ],
        ),
        (["u.txt", "gone.txt"], ["--columns", "input=u.txt,output=gone.txt"], ["gone.txt' does not exist"]),
        (
            ["u.txt", "y.txt"],
            ["--columns", "input=u.txt,output=y.txt:lvl"],
            [
                "no column 'lvl' for the output (its columns: level)",
                "did you mean 'level'",
                "--columns output=",
                "y.txt:level",
            ],
        ),
        (
            ["u.txt", "both.txt"],
            ["--columns", "input=u.txt,output=both.txt"],
            ["has 2 columns (0, 1)", "--columns output=", "both.txt:0"],
        ),
        (
            ["u.txt", "y.txt"],
            ["--columns", "input=u.txt,output=level"],
            ["the output 'level' names none of the files", "output=FILE:COLUMN"],
        ),
        (
            ["u.txt", "y.txt", "both.txt"],
            ["--columns", "input=u.txt,output=y.txt"],
            ["both.txt' is given but the mapping", "names none of its columns"],
        ),
        (["u.txt", "y.txt"], [], ["text table", "--columns input=", "u.txt,output=", "--rate HZ"]),
        (["both.txt"], [], ["--columns input=", "both.txt:0,output=", "both.txt:1"]),
    ],
)
def test_bad_joins_exit_2_with_one_line(lab, tmp_path, capsys, files, flags, phrases):
    folder, *_ = lab
    code, _, err = run(
        [
            "fit",
            *(folder / f for f in files),
            *flags,
            "--rate",
            "2",
            "--model",
            "physics",
            "--out",
            tmp_path / "m.eqx",
        ],
        capsys,
    )
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and lines[0].startswith("hybrid: error:"), err
    for phrase in phrases:
        assert phrase in lines[0], lines[0]
    assert not (tmp_path / "m.eqx").exists()


def test_a_missing_column_lists_the_columns_and_shows_the_flag(tmp_path):
    """Unmapped (t, v_in, w expected) and mapped: the file's names, and the flag written with them."""
    from hybrid import Recording

    lab = tmp_path / "lab.csv"
    lab.write_text("uEst,yEst\n1,2\n3,4\n5,6\n")
    with pytest.raises(InputError) as caught:
        Recording.load(lab)
    assert "found 'uEst', 'yEst'" in str(caught.value)
    assert "--columns input=uEst,output=yEst" in str(caught.value)
    with pytest.raises(InputError) as caught:
        load_mapped(lab, input="uest", output="yEst", rate=1)
    assert "its columns: uEst, yEst" in str(caught.value) and "--input uEst" in str(caught.value)


@pytest.mark.parametrize(
    "header, drive, output",
    [
        ("time,u,y", "u", "y"),
        ("Time (s),Voltage (V),Displacement (mm)", "Voltage (V)", "Displacement (mm)"),
        ("Index,t_s,Command,Laser", "Command", "Laser"),
    ],
)
def test_the_suggested_flags_read_the_lab_file(tmp_path, header, drive, output):
    """The refusal's example is guessed from the names (time, drive, output; an index skipped) and works as given."""
    import shlex

    from hybrid import Recording

    names = header.split(",")
    rng = np.random.default_rng(0)
    table = np.round(rng.normal(size=(50, len(names))), 6)  # as written to the file
    time = next(i for i, n in enumerate(names) if n.lower().startswith("t"))
    table[:, time] = np.arange(50) / 10.0
    if names[0] == "Index":
        table[:, 0] = np.arange(50)
    lab = tmp_path / "lab.csv"
    np.savetxt(lab, table, delimiter=",", header=header, comments="", fmt="%.9g")
    with pytest.raises(InputError) as caught:
        Recording.load(lab)
    words = shlex.split(str(caught.value).split("e.g. ", 1)[1])
    flags = dict(zip(words[::2], words[1::2]))
    assert set(flags) == {"--columns", "--time"}, words
    recording = Recording.load(lab, columns=flags["--columns"], time=flags["--time"])
    np.testing.assert_array_equal(recording.v_in, table[:, names.index(drive)])
    np.testing.assert_array_equal(recording.w, table[:, names.index(output)])
    assert recording.rate == pytest.approx(10.0)


def test_a_text_table_in_the_projects_columns_needs_no_mapping_and_one_with_a_header_gets_its_own(
    lab, tmp_path, capsys
):
    """A .tsv headed t, v_in, w fits as a .csv would; a logger's .tsv headed with its own names is refused
    with the flags for those names, which read it as given."""
    import shlex

    from hybrid import Recording

    folder, u, y = lab
    t = np.arange(u.size) / 2.0
    own = tmp_path / "own.tsv"
    np.savetxt(own, np.c_[t, u, y], delimiter="\t", header="t\tv_in\tw", comments="", fmt="%.9g")
    report = tmp_path / "fit.json"
    code, _, err = run(
        ["fit", own, "--physics", f"{folder / 'lag.py'}:Lag", "--model", "physics", "--max-steps", "20"]
        + ["--quiet", "--out", tmp_path / "m.eqx", "--json", report],
        capsys,
    )
    assert code == 0, err
    assert json.loads(report.read_text())["parameters"]["tau_s"] == pytest.approx(3.0, rel=0.2)

    logger = tmp_path / "logger.tsv"
    header = "Time (ms)\tDrive (V)\tTip (mm)"
    np.savetxt(logger, np.c_[1000 * t, u, y], delimiter="\t", header=header, comments="", fmt="%.9g")
    code, _, err = run(["fit", logger, "--model", "physics", "--out", tmp_path / "n.eqx"], capsys)
    assert code == 2 and "text table without the columns t, v_in, w" in err, err
    assert "its columns: Time (ms), Drive (V), Tip (mm)" in err
    words = shlex.split(err.split("e.g. ", 1)[1].split(" (its columns")[0])
    flags = dict(zip(words[::2], words[1::2]))
    assert set(flags) == {"--columns", "--time"}, words
    recording = Recording.load(logger, columns=flags["--columns"], time=flags["--time"])
    np.testing.assert_allclose(recording.v_in, u, rtol=1e-8)
    np.testing.assert_allclose(recording.w, y, rtol=1e-8)
    assert recording.rate == pytest.approx(2.0)
    assert not (tmp_path / "n.eqx").exists()


def test_joined_files_without_a_time_column_or_rate_are_told_their_time_columns(tmp_path, capsys):
    """A drive logged apart from a tracker's output, each file with its own 't': the refusal names them as
    FILE:COLUMN in the flag to give (the single-file message's '--time X_Value'), and that flag reads them."""
    import shlex

    t = np.arange(60) / 30.0
    np.savetxt(tmp_path / "drive.csv", np.c_[t, np.sin(t)], delimiter=",", header="t,v", comments="")
    np.savetxt(tmp_path / "tip.csv", np.c_[t, np.cos(t)], delimiter=",", header="t,w", comments="")
    files = [tmp_path / "drive.csv", tmp_path / "tip.csv"]
    code, _, err = run(
        ["fit", *files, "--columns", f"input={files[0]}:v,output={files[1]}:w", "--model", "physics"]
        + ["--out", tmp_path / "m.eqx"],
        capsys,
    )
    lines = [line for line in err.splitlines() if line.strip()]
    assert code == 2 and len(lines) == 1 and "no time column and no sampling rate" in lines[0], err
    assert (
        f"the column 't' of '{files[0]}' looks like one (so does the column 't' of '{files[1]}')" in lines[0]
    )
    flag = shlex.split(lines[0].split("(--time ", 1)[1].split(";", 1)[0])[0]
    assert flag == f"{files[0]}:t"
    record = load_mapped(files, columns=f"input={files[0]}:v,output={files[1]}:w", time=flag)
    assert record.rate == pytest.approx(30.0) and not (tmp_path / "m.eqx").exists()
