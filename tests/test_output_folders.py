"""Output folders (aev_ocp.results.claim_output_dir and the atomic writers): a folder of another run or of the
user is never clobbered, every command locks the folder it claims until it ends (a folder removed and made again is
locked again), names never lead outside results/, and temporaries never outlive an interrupted write."""

from __future__ import annotations

import fcntl
import os
import shutil
import signal
from pathlib import Path

import pytest
from cli_helpers import one_error, run_cli
from helpers import SMALL, _never, _run_study
from study_helpers import TINY_STUDY as STUDY
from study_helpers import write_tiny_study as _study

from aev_ocp import interrupts

# ----------------------------------------------------------------------------- output-folder locks


def _locked_by_someone(folder) -> bool:
    """Whether another open file description of folder's lock file cannot take the lock (flock treats each
    open() independently, even within one process)."""
    from aev_ocp.results import LOCK

    fd = os.open(folder / LOCK, os.O_RDWR | os.O_CREAT)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        return True
    finally:
        os.close(fd)
    return False


def test_a_folder_removed_and_made_again_is_locked_again(tmp_path):
    from aev_ocp.results import claim_output_dir, output_lock, release_output_locks

    out = tmp_path / "o"
    try:
        claim_output_dir(out, "simulate", "table1", None, ["a.csv"])  # held until the command ends
        assert _locked_by_someone(out)
        shutil.rmtree(out)  # a notebook removes the folder and runs again into the same name
        claim_output_dir(out, "simulate", "table1", None, ["a.csv"])
        assert _locked_by_someone(out)  # the new folder is locked too (before: the cached path said 'held')
        os.unlink(out / ".aev-ocp.lock")  # only the lock file removed: taken again as well
        with output_lock(out):
            assert _locked_by_someone(out)
        assert _locked_by_someone(out)  # the claim's lock outlives the inner block, as before
        release_output_locks()
        assert not _locked_by_someone(out)
    finally:
        release_output_locks()


# ----------------------------------------------------------------------------- from the issue-28 re-probe (test_reprobe.py)
EXIT_OK, EXIT_BAD_INPUT, EXIT_INTERRUPTED = 0, 2, 130


def test_output_folder_that_cannot_be_created_is_one_short_line(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """--out with a 6000-character path printed 'File name too long: <the whole path>', a dangling symbolic link
    'File exists: link'; both now name the output folder (shortened) and why, exit 2."""
    scen = tmp_path / "s.toml"
    scen.write_text(SMALL, encoding="utf-8")
    long_out = "/".join(["b" * 200] * 30)
    code, _, err = run_cli(["simulate", str(scen), "--no-plots", "--out", str(tmp_path / long_out)], capsys)
    line = one_error(err)
    assert code == EXIT_BAD_INPUT and line.startswith("aev-ocp: error: output folder ") and len(line) < 300, line
    assert "characters) cannot be created or read (File name too long)" in line
    (tmp_path / "link").symlink_to(tmp_path / "nowhere" / "x")
    code, _, err = run_cli(["simulate", str(scen), "--no-plots", "--out", str(tmp_path / "link")], capsys)
    line = one_error(err)
    assert code == EXIT_BAD_INPUT and "is a symbolic link to" in line and "which does not exist" in line, line


# ----------------------------------------------------------------------------- from the third reliability probe (test_reprobe3.py)
def test_foreign_folder_message_has_no_none_source(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    """A ring experiment has no scenario file: the refusal said "of scenario 'sugiyama' (None)"."""
    out = str(tmp_path / "o")
    assert run_cli(["ring", "sugiyama", "--t-end-s", "2.5", "--out", out, "--no-plots"], capsys)[0] == 0
    rc, _, err = run_cli(["stability", "--law", "ovm", "--linear-only", "--no-plots", "--out", out], capsys)
    line = one_error(err)
    assert rc == 2 and "holds the results of 'aev-ocp ring' of scenario 'sugiyama';" in line and "None" not in line


# ----------------------------------------------------------------------------- from the issue-28 surfaces probe (test_reliability_surfaces.py)


def _foreign_lock(out: Path) -> int:
    """Hold the folder lock as another process would: an flock on a descriptor of our own (output_lock is
    re-entrant within one process, so it cannot stand for a second run)."""
    import fcntl

    from aev_ocp.results import LOCK

    out.mkdir(parents=True, exist_ok=True)
    fd = os.open(out / LOCK, os.O_RDWR | os.O_CREAT)
    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    return fd


def test_study_refuses_a_users_folder_and_another_study_but_resumes_its_own(tmp_path, capsys):
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "table.csv").write_text("my,own\n1,2\n")
    f = _study(tmp_path)
    rc, err = _run_study(tmp_path, f, mine, capsys)
    assert rc == 2 and "table.csv" in one_error(err)
    assert (mine / "table.csv").read_text() == "my,own\n1,2\n" and not (mine / "points").exists()
    out = tmp_path / "o"
    assert _run_study(tmp_path, f, out, capsys)[0] == 0
    before = (out / "table.jsonl").read_text()
    other = _study(tmp_path, "other")
    rc, err = _run_study(tmp_path, other, out, capsys)
    assert rc == 2 and "tiny" in one_error(err) and (out / "table.jsonl").read_text() == before
    rc, err = _run_study(tmp_path, f, out, capsys)  # the same study resumes: nothing recomputed
    assert rc == 0 and "(4 stored, 0 failed)" in err


@pytest.mark.parametrize("name", ["../../../escaped", "/tmp/abs_study_name", ".hidden", "a/b"])
def test_study_name_must_not_lead_outside_results(tmp_path, capsys, monkeypatch, name):
    monkeypatch.chdir(tmp_path)
    f = tmp_path / "s.toml"
    f.write_text(STUDY.replace("{name}", name))
    rc, _, err = run_cli(["study", str(f), "--in-process"], capsys)
    assert rc == 2 and "name = " in one_error(err)
    assert not (tmp_path / "results").exists() and not Path("/tmp/abs_study_name/points").exists()


@pytest.mark.parametrize(
    "argv, claimed, work",
    [
        (["stability", "--law", "ovm", "--linear-only"], "gain.png", "aev_ocp.stability.run.run_stability"),
        (["ring", "sugiyama", "--t-end-s", "5"], "ring.json", "aev_ocp.ring.run.sugiyama"),
        (
            ["stability", "--law", "ovm", "--ring", "22", "--density-per-km", "47"],
            "ring_stability.json",
            "aev_ocp.stability.ring.ring_stability",
        ),
    ],
)
def test_stability_and_ring_refuse_a_users_folder_before_any_work(tmp_path, capsys, monkeypatch, argv, claimed, work):
    monkeypatch.setattr(work, _never(work))  # refused before the analysis, not after
    (tmp_path / claimed).write_bytes(b"mine")
    rc, _, err = run_cli([*argv, "--out", str(tmp_path)], capsys)
    assert rc == 2 and claimed in one_error(err) and (tmp_path / claimed).read_bytes() == b"mine"


def test_a_second_study_into_a_locked_folder_is_refused(tmp_path, capsys):
    out = tmp_path / "o"
    fd = _foreign_lock(out)
    try:
        rc, err = _run_study(tmp_path, _study(tmp_path), out, capsys)
    finally:
        os.close(fd)
    assert rc == 2 and "in use by another aev-ocp run" in one_error(err) and not (out / "points").exists()
    assert _run_study(tmp_path, _study(tmp_path), out, capsys)[0] == 0  # released with the other run


def test_figures_use_unique_temporaries_and_leave_none_on_interrupt(tmp_path, monkeypatch):
    import matplotlib.figure

    from aev_ocp.study.report import _save

    names = []
    real = matplotlib.figure.Figure.savefig

    def spy(self, fname, *a, **k):  # noqa: ANN001
        names.append(Path(fname).name)
        real(self, fname, *a, **k)

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", spy)
    import matplotlib.pyplot as plt

    for _ in range(2):
        _save(plt.figure(), tmp_path / "fig_a.png")
    assert len(set(names)) == 2 and all(n != "fig_a.png" for n in names)

    def boom(self, fname, *a, **k):  # noqa: ANN001
        Path(fname).write_bytes(b"half")
        raise KeyboardInterrupt

    monkeypatch.setattr(matplotlib.figure.Figure, "savefig", boom)
    with pytest.raises(KeyboardInterrupt):
        _save(plt.figure(), tmp_path / "fig_b.png")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["fig_a.png"]


@pytest.mark.parametrize(
    "argv",
    [
        ["simulate", "table1", "--set", "simulation.t_end=1.5", "--set", "platoon.followers=2", "--no-plots"],
        ["mpc-export", "mpc_paper_single"],
        ["stability", "--law", "ovm", "--linear-only", "--no-plots"],
        ["ring", "sugiyama", "--t-end-s", "3", "--no-plots"],
    ],
)
def test_every_command_refuses_a_folder_another_run_is_writing(tmp_path, capsys, argv):
    out = tmp_path / "o"
    fd = _foreign_lock(out)
    try:
        rc, _, err = run_cli([*argv, "--out", str(out)], capsys)
    finally:
        os.close(fd)
    assert rc == 2 and "in use by another aev-ocp run" in one_error(err)
    assert sorted(p.name for p in out.iterdir()) == [".aev-ocp.lock"]  # nothing written beside the lock


def test_claim_holds_the_lock_until_the_command_ends_and_is_reentrant(tmp_path, capsys):
    import fcntl

    from aev_ocp.results import LOCK, claim_output_dir, output_lock, release_output_locks

    done = tmp_path / "done"  # a command that returned has released its folder: a second process may write
    assert run_cli(["stability", "--law", "ovm", "--linear-only", "--no-plots", "--out", str(done)], capsys)[0] == 0
    os.close(_foreign_lock(done))
    out = tmp_path / "o"
    with output_lock(out):  # a study holds the lock and claims its own folder inside it
        claim_output_dir(out, "study", "s", None, ["table.csv"])
    fd = os.open(out / LOCK, os.O_RDWR)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # released with the block
        fcntl.flock(fd, fcntl.LOCK_UN)
        claim_output_dir(out, "study", "s", None, ["table.csv"])
        with pytest.raises(BlockingIOError):  # held after the claim returned: the command is still running
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        release_output_locks()
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    finally:
        os.close(fd)


@pytest.mark.parametrize(
    "setup, argv, word",
    [
        (
            "fifo-marker",
            ["simulate", "table1", "--no-plots", "--set", "simulation.t_end=1.5"],
            "not a file aev-ocp wrote",
        ),
        ("prop31.json", ["ocp", "prop31", "--N", "20", "--no-refine"], "prop31.json"),
        ("notes.txt", ["ocp", "prop31", "--N", "20", "--no-refine"], "notes.txt"),
        ("space_time_all_human.png", ["ring", "sugiyama", "--t-end-s", "3"], "space_time_all_human.png"),
    ],
)
def test_outputs_not_listed_or_odd_markers_never_replace_a_users_entry(tmp_path, capsys, setup, argv, word):
    from aev_ocp.results import MARKER

    out = tmp_path / "o"
    out.mkdir()
    f = out / (MARKER if setup == "fifo-marker" else setup)
    if setup == "fifo-marker":
        os.mkfifo(f)
    else:
        f.write_bytes(b"mine")
    rc, _, err = run_cli([*argv, "--out", str(out)], capsys)
    assert rc == 2 and word in one_error(err)
    assert sorted(p.name for p in out.iterdir()) == [f.name]
    assert setup == "fifo-marker" or f.read_bytes() == b"mine"


def test_an_interrupt_right_after_the_temporary_is_created_leaves_nothing(tmp_path, monkeypatch):
    """The window between mkstemp creating the file and the code that removes it: a Ctrl-C there is held back
    (interrupts.deferred) until the removal is armed, so it still interrupts and leaves no temporary."""
    import tempfile

    from aev_ocp.results import write_atomic

    real = tempfile.mkstemp

    def mkstemp(*a, **k):  # noqa: ANN002, ANN003, ANN202
        out = real(*a, **k)
        os.kill(os.getpid(), signal.SIGINT)  # Python runs the handler at the next instruction: before the return
        return out

    monkeypatch.setattr(tempfile, "mkstemp", mkstemp)
    with interrupts.handle_signals():
        with pytest.raises(KeyboardInterrupt):
            write_atomic(tmp_path / "x.json", "{}")
        assert interrupts.interrupted() == signal.SIGINT
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(tempfile, "mkstemp", real)
    with interrupts.handle_signals():  # no signal: deferred() changes nothing
        write_atomic(tmp_path / "x.json", "{}")
    assert [p.name for p in tmp_path.iterdir()] == ["x.json"]
