"""Who holds a run folder's lock, read without importing the runtime (and so torch): the sweep
and its batched backend both ask before they touch a run folder; and the clearing of a partial
run's folder, which both do."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

RUN_LOCK = "run.lock"  # a3c_runtime.run_folder.LOCK_FILE: held by the process training in a run
# what a run refused for that lock says (a3c_runtime.run_folder); a row that an older sweep
# recorded as failed with it is a run that was in use, not a failed one
IN_USE_TEXT = "is in use by process"


def run_holder(run_dir: Path) -> str | None:
    """The process that holds the run folder's lock (its pid as the lock file says, or '?'),
    or None when no process does. The lock is a3c_runtime.run_folder's POSIX record lock: it is
    taken and given back at once here, so that the run started next can take it."""
    try:
        import fcntl
    except ImportError:  # no such locks here: the run itself refuses a held folder
        return None
    try:
        fd = os.open(run_dir / RUN_LOCK, os.O_RDWR)  # never created here
    except OSError:
        return None  # no lock file (no run there yet, or it ended): nobody holds it
    try:
        fcntl.lockf(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        return os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
    else:
        fcntl.lockf(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)  # also gives back a lock taken above


def clear_run_folder(run_dir: Path) -> None:
    """Empty the folder of a partial run that wrote no checkpoint, for the run to start again,
    all but its lock file: removing that would let two processes lock the folder at once (one
    the removed file, one a new one). A run folder that is a link is the folder it points to,
    as the run itself writes there; a link in it is removed, never followed."""
    run_dir.mkdir(parents=True, exist_ok=True)
    for path in run_dir.iterdir():
        if path.name == RUN_LOCK:
            continue
        if path.is_dir() and not path.is_symlink():
            shutil.rmtree(path)
        else:
            path.unlink()
