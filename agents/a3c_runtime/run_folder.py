"""The run folder: where it is, that it can be written, and that one process at a time trains
into it (an OS lock, held by the training process and released by the kernel when it ends, so a
killed run can be resumed at once; a process that ends normally also removes the lock file)."""

from __future__ import annotations

import contextlib
import fcntl
import os
import time
from pathlib import Path
from typing import Any

from .checkpoints import partial_path
from .flags import UsageError

LOCK_FILE = "run.lock"


def run_folder_path(args: Any, resuming: bool) -> Path:
    """--run-dir; a resumed run's own folder (its checkpoint's); or a new
    runs_root/<env>__<script>__<seed>__<time>."""
    if args.run_dir:
        return Path(args.run_dir)
    if resuming:
        return Path(args.resume).resolve().parent
    root = Path(args.runs_root)
    if root.exists() and not root.is_dir():
        raise UsageError(f"--runs-root {root} is not a folder")
    env = args.env.replace("/", "-")  # ALE/Breakout-v5: one folder, not ALE/<run>
    return root / f"{env}__{args.exp_name}__{args.seed}__{int(time.time())}"


RUN_FILES = ("checkpoint.pt", "evaluations.csv", "events.out.tfevents.*")
WRITTEN_ATOMICALLY = ("checkpoint.pt", "evaluations.csv")  # through a temp file (partial_path)


def resume_folder(args: Any) -> RunFolder:
    """--resume's run folder, locked: the checkpoint's own, or a --run-dir that holds no other
    run (check_no_run_in: a resume never mixes its run into another's folder)."""
    path = run_folder_path(args, resuming=True)
    own = path.resolve() == Path(args.resume).resolve().parent
    return RunFolder(path, new_run=not own)


def check_no_run_in(path: Path) -> None:
    """A new run's folder holds no other run: a fresh attempt never mixes with a dead one."""
    found = sorted({f.name for pattern in RUN_FILES for f in path.glob(pattern)})
    if not found:
        return
    if (path / "checkpoint.pt").exists():
        todo = (
            f"resume it (--resume {path / 'checkpoint.pt'}), remove it, or pass another --run-dir"
        )
    else:
        todo = f"remove it (rm -r -- {path}) or pass another --run-dir"
    raise UsageError(f"the run folder {path} holds another run ({', '.join(found[:3])}): {todo}")


class RunFolder:
    """The run folder, created if need be and locked for this process (`close` releases it and
    removes the lock file, and the folder if this process created it and wrote nothing there).
    UsageError, with nothing created, when it cannot be made or written, or another process
    holds it."""

    def __init__(self, path: Path, new_run: bool = False):
        self.path = path
        if path.exists() and not path.is_dir():
            raise UsageError(f"cannot use {path} as the run folder: it is a file")
        if new_run:
            check_no_run_in(path)
        self.created = not path.exists()
        try:
            path.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise UsageError(f"cannot create the run folder {path}: {e.strerror or e}") from e
        if not os.access(path, os.W_OK | os.X_OK):
            raise UsageError(f"cannot write into the run folder {path}: permission denied")
        self.lock = self._lock(path / LOCK_FILE)
        self.owner = os.getpid()  # a forked child holds no lock: it must not remove the file
        for name in WRITTEN_ATOMICALLY:  # a file half written when its run was killed: only
            with contextlib.suppress(OSError):  # the run's own temp files, never a user's
                partial_path(path / name).unlink()

    @staticmethod
    def _lock(lock_path: Path) -> int:
        # a POSIX record lock: held by this process only (forked workers do not inherit it) and
        # released by the kernel when the process ends, however it ends
        while True:
            try:
                fd = os.open(lock_path, os.O_RDWR | os.O_CREAT, 0o644)
            except OSError as e:
                raise UsageError(f"cannot write into the run folder {lock_path.parent}: {e}") from e
            try:
                fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                os.close(fd)
                raise UsageError(
                    f"the run folder {lock_path.parent} is in use by process {holder} (a run or "
                    "resume training there); wait for it to end or stop it"
                ) from None
            # the last holder removes the file when it closes: a lock taken on the file it
            # removed guards nothing, so lock the file now at the path instead
            try:
                if os.path.samestat(os.fstat(fd), os.stat(lock_path)):
                    break
            except FileNotFoundError:
                pass
            os.close(fd)
        with contextlib.suppress(OSError):  # the PID only names the holder to a second process
            pid = f"{os.getpid()}\n".encode()
            os.pwrite(fd, pid, 0)  # written, then cut to length: never an empty file
            os.ftruncate(fd, len(pid))
        return fd

    def close(self) -> None:
        if self.lock >= 0:
            owner = os.getpid() == self.owner
            if owner:
                with contextlib.suppress(OSError):  # removed while held: no one else can take it
                    (self.path / LOCK_FILE).unlink()
            os.close(self.lock)  # closing releases the lock
            self.lock = -1
            if owner and self.created:  # e.g. a refused --resume into a new --run-dir
                with contextlib.suppress(OSError):
                    self.path.rmdir()  # only if empty
