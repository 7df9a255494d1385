"""a3c_runtime.run_folder: an unusable run folder is a one-line error before anything is
created, and one process at a time trains into a run folder (an OS lock that the kernel
releases when its holder dies)."""

import os
import signal

import a3c_runtime as runtime
import pytest
from a3c_runtime.flags import UsageError
from a3c_runtime.run_folder import RunFolder
from conftest import FORK, load_script, main_exit, shared_for, tiny_args

import catch_env  # noqa: F401  (registers Catch-v0)


def _hold(path, ready, release) -> None:
    folder = RunFolder(path)
    ready.set()
    release.wait(30)
    folder.close()


def test_a_second_process_is_refused_naming_the_holder_until_the_holder_dies(tmp_path):
    ready, release = FORK.Event(), FORK.Event()
    holder = FORK.Process(target=_hold, args=(tmp_path / "run", ready, release))
    holder.start()
    assert ready.wait(30)
    with pytest.raises(UsageError, match=f"in use by process {holder.pid} "):
        RunFolder(tmp_path / "run")
    os.kill(holder.pid, signal.SIGKILL)  # the kernel releases its lock
    holder.join(30)
    RunFolder(tmp_path / "run").close()


def _try_lock(path, results) -> None:
    try:
        RunFolder(path).close()
        results.put("locked")
    except UsageError as e:
        results.put(str(e))


def test_the_lock_is_released_on_close(tmp_path):
    """POSIX locks are per process: another process tells whether close released it."""
    folder = RunFolder(tmp_path)
    results = FORK.SimpleQueue()
    for expected in ("in use by process", "locked"):
        child = FORK.Process(target=_try_lock, args=(tmp_path, results))
        child.start()
        child.join(30)
        assert expected in results.get()
        folder.close()


@pytest.mark.parametrize("flag", ["--runs-root", "--run-dir"])
def test_a_file_as_the_run_folder_exits_2_in_one_line_creating_nothing(
    flag, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "file").write_text("not a folder")
    target = "file" if flag == "--runs-root" else "file/run"
    code, err = main_exit(load_script("a3c_ff"), [flag, target], monkeypatch, capsys)
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file"]


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into any folder")
def test_a_folder_without_write_permission_exits_2(tmp_path, monkeypatch, capsys):
    locked = tmp_path / "locked"
    locked.mkdir(mode=0o555)
    code, err = main_exit(load_script("a3c_ff"), ["--runs-root", str(locked)], monkeypatch, capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert list(locked.iterdir()) == []


def test_a_folder_that_cannot_be_written_or_entered_is_refused_even_as_root(
    tmp_path, monkeypatch, capsys
):
    """Root writes into any folder, so the test above is skipped there: here the folder's
    permissions are what os.access reports, writable but not enterable, then the reverse; both
    are refused in one line (exit 2), as a folder without write permission is."""
    access = os.access
    for lacking in (os.X_OK, os.W_OK):
        monkeypatch.setattr(
            os,
            "access",
            lambda path, mode, lacking=lacking: not mode & lacking and access(path, mode),
        )
        argv = [
            "--runs-root",
            str(tmp_path / "runs"),
            "--total-timesteps",
            "50",
            "--num-workers",
            "1",
            "--eval-episodes",
            "1",
        ]  # (a run let through ends soon)
        code, err = main_exit(load_script("a3c_ff"), argv, monkeypatch, capsys)
        assert code == 2 and "cannot write into the run folder" in err and err.count("\n") == 1
        monkeypatch.setattr(os, "access", access)


def test_close_removes_the_lock_file_and_a_folder_it_created_empty(tmp_path):
    kept = RunFolder(tmp_path)  # an existing folder: kept
    assert (tmp_path / "run.lock").read_text() == f"{os.getpid()}\n"
    kept.close()
    assert tmp_path.is_dir() and list(tmp_path.iterdir()) == []
    created = RunFolder(tmp_path / "new")  # e.g. a refused --resume into a new --run-dir
    created.close()
    assert list(tmp_path.iterdir()) == []
    written = RunFolder(tmp_path / "run")
    (written.path / "evaluations.csv").write_text("global_step\n")
    written.close()
    assert sorted(p.name for p in (tmp_path / "run").iterdir()) == ["evaluations.csv"]


def test_a_lock_taken_on_a_removed_lock_file_is_taken_again(tmp_path, monkeypatch):
    """The race that removing the file opens: a process opens run.lock, its holder removes it
    and closes, and a third process creates a new one. A lock on the removed file would let two
    processes train there: the lock must end up on the file at the path."""
    import fcntl

    import a3c_runtime.run_folder as run_folder

    lockf, calls = fcntl.lockf, []

    def replaced_first(fd, operation):
        if not calls:  # the file this process opened is replaced before it locks it
            (tmp_path / "run.lock").unlink()
            (tmp_path / "run.lock").write_text("")
        calls.append(fd)
        return lockf(fd, operation)

    monkeypatch.setattr(run_folder.fcntl, "lockf", replaced_first)
    folder = RunFolder(tmp_path)
    assert len(calls) == 2
    assert os.path.samestat(os.fstat(folder.lock), os.stat(tmp_path / "run.lock"))
    folder.close()


@pytest.mark.parametrize(
    ("files", "advice"),
    [
        (["evaluations.csv", "events.out.tfevents.1.vm.2.0"], "remove it (rm -r -- "),
        (["checkpoint.pt", "evaluations.csv"], "resume it (--resume "),
    ],
)
def test_a_new_run_never_mixes_with_another_in_its_folder(
    tmp_path, monkeypatch, capsys, files, advice
):
    """A fresh attempt into the folder of a dead one (its evaluations, its events) would append
    to them: refused in one line saying what to do, with nothing created or changed."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    for name in files:
        (run_dir / name).write_text("old\n")
    with pytest.raises(UsageError, match="holds another run"):
        RunFolder(run_dir, new_run=True)
    argv = ["--total-timesteps", "100", "--run-dir", str(run_dir)]
    code, err = main_exit(load_script("a3c_ff"), argv, monkeypatch, capsys)
    assert code == 2 and err.count("\n") == 1 and advice in err, err
    assert sorted(p.name for p in run_dir.iterdir()) == sorted(files)
    assert all((run_dir / name).read_text() == "old\n" for name in files)
    RunFolder(run_dir).close()  # a resumed run's folder is its own: no such check


def test_a_namespaced_env_id_names_one_run_folder(tmp_path):
    """ALE/Breakout-v5 (the v5 ids, sticky actions) gives runs/ALE-Breakout-v5__..., one folder
    in --runs-root, not a folder ALE/ holding the run."""
    from types import SimpleNamespace

    from a3c_runtime.run_folder import run_folder_path

    args = SimpleNamespace(run_dir=None, runs_root=str(tmp_path), env="ALE/Breakout-v5",
                           exp_name="a3c_ff", seed=1)  # fmt: skip
    path = run_folder_path(args, resuming=False)
    assert path.parent == tmp_path and path.name.startswith("ALE-Breakout-v5__a3c_ff__1__")


def test_a_resume_never_mixes_its_run_into_another_runs_folder(tmp_path, monkeypatch, capsys):
    """--resume A/checkpoint.pt --run-dir B, B holding another run: refused in one line, B left
    as it was; into its own folder, or an empty one, the resume goes on."""
    module = load_script("a3c_ff")
    args = tiny_args(module, total_timesteps=100)
    a, b = tmp_path / "a", tmp_path / "b"
    for folder, step in ((a, 10), (b, 20)):
        folder.mkdir()
        shared = shared_for(module, args)
        shared.steps[0] = step
        runtime.save_checkpoint(folder / "checkpoint.pt", shared, args, 1.0, "a3c_ff.py")
        (folder / "evaluations.csv").write_text(f"global_step,mean_return\n0,0.0\n{step},0.5\n")
    before = {p.name: p.read_bytes() for p in b.iterdir()}

    def started(*args, **kwargs):
        raise AssertionError("a run was started")

    monkeypatch.setattr("a3c_runtime.a3c.Supervisor", started)
    argv = ["--resume", str(a / "checkpoint.pt"), "--run-dir", str(b)]
    code, err = main_exit(module, argv, monkeypatch, capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert f"the run folder {b} holds another run" in err and f"--resume {b}" in err, err
    assert {p.name: p.read_bytes() for p in b.iterdir()} == before
    for folder in (a, tmp_path / "empty"):  # its own folder; a new one: the gate passes it on
        with pytest.raises(AssertionError, match="a run was started"):
            main_exit(module, ["--resume", str(a / "checkpoint.pt"), "--run-dir", str(folder)],
                      monkeypatch, capsys)  # fmt: skip


def test_a_run_removes_only_the_temp_files_it_made(tmp_path):
    """A killed run's half-written files (write_atomically's, named for it) go when its folder
    is taken again; a user's *.tmp file, or any other, stays."""
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    own = [run_dir / "checkpoint.pt.a3c-partial", run_dir / "evaluations.csv.a3c-partial"]
    users = [run_dir / "notes.tmp", run_dir / "checkpoint.pt.tmp", run_dir / "x.a3c-partial"]
    for new_run in (True, False):  # a new run's folder, a resumed one's
        for path in own + users:
            path.write_text("half\n")
        RunFolder(run_dir, new_run=new_run).close()
        assert all(path.read_text() == "half\n" for path in users)
        assert sorted(p.name for p in run_dir.iterdir()) == sorted(p.name for p in users)
    assert runtime.checkpoints.partial_path(run_dir / "checkpoint.pt") == own[0]
