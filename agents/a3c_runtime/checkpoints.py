"""Checkpoints: written atomically (a temp file, flushed to disk, then a rename) so that a crash
or a full disk never leaves a corrupt one or a partial file, and sealed with a SHA-256 of their
bytes; read safely (every zip member's CRC and the seal checked, then `torch.load` with
`weights_only=True`, which builds tensors, numbers, strings, lists, tuples and dicts and runs
no code), so that a missing, changed, truncated, unsealed, foreign or code-carrying checkpoint
is a one-line UsageError before anything uses it; restored into the shared network and
optimizer for --resume.

The seal guards against accidents (a flipped bit, a truncated copy, a stripped comment), not
against someone: anyone can recompute it. What makes a shared checkpoint harmless is that
loading one never executes it."""

import contextlib
import hashlib
import io
import os
import pickle
import shlex
import struct
import zipfile
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch
import torch.nn as nn

from .flags import UsageError
from .hogwild import Shared

CHECKPOINT_FORMAT = "a3c-checkpoint-v2"  # every part of the safe form; "script" always set
# v1 held the workers' states pickled, so a v1 checkpoint is never loaded: its owner converts it
# (python -m a3c_tools.convert_checkpoint, which unpickles it on that explicit request)
UNSAFE_FORMATS = ("a3c-checkpoint-v1",)
# Chapter 8's ideas were flags of the thesis scripts before each became a script of its own in
# agents/future_work/: a checkpoint an older thesis script wrote with one of them set belongs to
# that script, which plays and resumes it; the thesis script refuses it, naming the script.
MOVED_FLAGS = {
    "a3c_lpq.py": {
        ("value_head", "prototypes"): "future_work/a3c_lpq_value_head.py",
        ("prototype_init", "data"): "future_work/a3c_lpq_data_init.py",
        ("prototype_growth", True): "future_work/a3c_lpq_growth.py",
    },
    "a3c_glpq.py": {
        ("value_head", "prototypes"): "future_work/a3c_glpq_value_head.py",
        ("prototype_init", "data"): "future_work/a3c_glpq_data_init.py",
        ("prototype_growth", True): "future_work/a3c_glpq_growth.py",
    },
    "a3c_lws.py": {("lws_centroid_source", "online"): "future_work/a3c_lws_online.py"},
}
# The seal: the zip's comment holds the SHA-256 of every byte before it. torch reads no zip
# comment, and the CRCs cover only the members' data, not the headers between them.
SEAL_PREFIX = b"a3c-sha256:"
END_OF_ARCHIVE = b"PK\x05\x06"  # the end-of-central-directory record: 22 bytes + the comment


def save_checkpoint(
    path: Path,
    shared: Shared,
    args: Any,
    wall_time: float,
    script: str = "",
    snapshot: dict | None = None,
) -> None:
    """Write atomically (temp file + rename) so that a crash never leaves a corrupt checkpoint.
    Of theta, the optimizer statistics and the global step as they are in `shared`, or as a
    worker copied them at a checkpoint mark (`snapshot`: model, optimizer, global_step); either
    may add what an exact resume needs (a3c_runtime.snapshots): `workers`, each worker's state
    in the safe form (snapshots.saved_state), and `pending_evaluations`, the (step, theta)
    evaluations not taken yet."""
    snapshot = snapshot or {}
    checkpoint = {
        "format": CHECKPOINT_FORMAT,
        "script": script,
        "network": type(shared.model).__name__,
        "model": snapshot.get("model")
        or {k: v.detach().clone() for k, v in shared.model.state_dict().items()},
        "optimizer": snapshot.get("optimizer") or shared.optimizer.state_dict(),
        "optimizer_name": args.optimizer,
        "global_step": snapshot.get("global_step", shared.global_step()),
        "wall_time": wall_time,
        "args": asdict(args),
        "workers": snapshot.get("workers", {}),
        "pending_evaluations": snapshot.get("pending_evaluations", []),
    }
    buffer = io.BytesIO()  # serialised first, so that a failed write is the OS's own error
    torch.save(checkpoint, buffer)
    write_atomically(path, seal(buffer.getvalue()))


def seal(archive: bytes) -> bytes:
    """The zip archive torch.save wrote, with the SHA-256 of its bytes as the zip's comment.
    ValueError if the archive does not end in a comment-less end-of-central-directory record
    (a layout this seal does not know: nothing unsealed is ever written)."""
    if archive[-22:-18] != END_OF_ARCHIVE or archive[-2:] != b"\x00\x00":
        raise ValueError("the archive does not end in a comment-less end-of-central-directory")
    length = len(SEAL_PREFIX) + hashlib.sha256().digest_size * 2
    head = archive[:-2] + struct.pack("<H", length)  # the comment's length is sealed too
    return head + SEAL_PREFIX + hashlib.sha256(head).hexdigest().encode()


def verify_checkpoint(data: bytes) -> str | None:
    """What is wrong with a checkpoint's bytes, or None if nothing: an archive that is no zip
    (truncated, another format), a member whose CRC fails, a zip that torch did not write, no
    seal (NO_SEAL), a seal that does not match its bytes."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            bad_member = archive.testzip()  # reads every member, checking its CRC
            comment, names = archive.comment, archive.namelist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, ValueError) as e:
        return f"not a whole zip archive ({e})"
    if bad_member is not None:
        return f"{bad_member} fails its CRC check"
    if not any(name.endswith("/data.pkl") for name in names):
        return "not a torch file (a zip archive without data.pkl)"
    if not comment:
        return NO_SEAL
    head = data[: len(data) - len(comment)]
    if comment != SEAL_PREFIX + hashlib.sha256(head).hexdigest().encode():
        return "its bytes do not match the SHA-256 it was written with"
    return None


NO_SEAL = "it carries no seal"


def convert_command(path: str) -> str:
    """The command that converts a checkpoint its owner trusts into the safe, sealed form."""
    return shlex.join(["python", "-m", "a3c_tools.convert_checkpoint", path])


def read_checkpoint(path: str, flag: str | None = None) -> dict:
    """The checkpoint at path, its bytes verified and then loaded safely (weights_only=True:
    nothing in it runs), or a one-line UsageError saying what is wrong with it. Checks the
    format, not whose it is (load_checkpoint does)."""
    check_checkpoint_path(path, flag)
    try:
        data = Path(path).read_bytes()  # read once: what is verified is what is loaded
    except OSError as e:
        raise UsageError(f"cannot read checkpoint {path!r}: {e.strerror or e}") from e
    problem = verify_checkpoint(data)
    if problem == NO_SEAL:
        raise UsageError(
            f"checkpoint {path!r} carries no seal (written before checkpoints were sealed and "
            f"safe to load, or changed since), so it is not loaded; if you trust it, convert "
            f"it: {convert_command(path)}"
        )
    if problem is not None:
        raise UsageError(f"checkpoint {path!r} is corrupt: {problem}")
    try:
        checkpoint = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:  # an object that is not data: never built, never run
        lines = str(e).strip().splitlines()
        detail = next((line.strip() for line in lines if "Unsupported" in line), None)
        raise UsageError(
            f"checkpoint {path!r} cannot be loaded safely: it holds more than data "
            f"({detail or (lines or [type(e).__name__])[0]}); if it is yours, from before "
            f"checkpoints were safe to load, convert it: {convert_command(path)}"
        ) from None
    except Exception as e:
        detail = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise UsageError(f"checkpoint {path!r} is corrupt or not a torch file: {detail}") from e
    if isinstance(checkpoint, dict) and checkpoint.get("format") in UNSAFE_FORMATS:
        raise UsageError(
            f"checkpoint {path!r} was written before checkpoints were safe to load, and is not "
            f"loaded; if you trust it, convert it: {convert_command(path)}"
        )
    if not isinstance(checkpoint, dict) or checkpoint.get("format") != CHECKPOINT_FORMAT:
        raise UsageError(f"{path!r} is not a checkpoint written by the agent scripts")
    return checkpoint


class WriteFailed(Exception):
    """A run's file could not be written (a full disk, a read-only folder, a file-size limit)."""

    def __init__(self, path: Path | str, error: OSError):
        self.path, self.error = Path(path), error
        super().__init__(f"could not write {path}: {error.strerror or error}")


def write_atomically(path: Path, data: bytes | memoryview) -> None:
    """path's new content, all or nothing: a temp file beside it, flushed to disk, renamed over
    it. On failure the temp file is removed and the old file is untouched: WriteFailed."""
    tmp = path.with_name(path.name + ".tmp")
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as e:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise WriteFailed(path, e) from e


def checkpoint_step(path: Path) -> int | None:
    """The global step of a checkpoint that reads safely (read_checkpoint), else None."""
    try:
        return int(read_checkpoint(str(path))["global_step"])
    except (UsageError, KeyError, TypeError, ValueError):
        return None


def check_checkpoint_path(path: str, flag: str | None = None) -> None:
    """UsageError unless path is a file: a missing path, or a folder (naming the checkpoint in
    it, if it holds one, as `flag PATH`)."""
    if os.path.isdir(path):
        inside = os.path.join(path, "checkpoint.pt")
        if os.path.isfile(inside):
            command = f"{flag} {inside}" if flag else inside
            raise UsageError(f"checkpoint {path!r} is a folder: pass its checkpoint, {command}")
        raise UsageError(f"checkpoint {path!r} is a folder, and holds no checkpoint.pt")
    if not os.path.isfile(path):
        raise UsageError(f"checkpoint {path!r} does not exist")


def load_checkpoint(path: str, agent: Any, flag: str | None = None) -> dict:
    """Load a checkpoint of this script (read_checkpoint), or raise UsageError saying what is
    wrong with it."""
    checkpoint = read_checkpoint(path, flag)
    script = checkpoint.get("script")
    moved = moved_script(checkpoint)
    if moved is not None:
        owner, flag, value = moved
        if owner != agent.script:
            raise UsageError(
                f"checkpoint {path!r} was trained by {script} with --{flag.replace('_', '-')} "
                f"{value}, now a script of its own: use python agents/{owner}"
            )
    elif script and script != agent.script:
        raise UsageError(
            f"checkpoint {path!r} was written by {script}, not {agent.script}: "
            f"use python agents/{script}"
        )
    # (every script's network class is ActorCritic, so the stored "network" name tells nothing;
    # the script name above, or the tensors' shapes in load_network, refuse another's checkpoint)
    return checkpoint


def moved_script(checkpoint: dict) -> tuple[str, str, Any] | None:
    """(the future-work script, the flag, its value) of a checkpoint that a thesis script wrote
    with a chapter-8 flag set (MOVED_FLAGS), else None."""
    trained = checkpoint.get("args", {})
    for (flag, value), owner in MOVED_FLAGS.get(checkpoint.get("script"), {}).items():
        if trained.get(flag) == value:
            return owner, flag, value
    return None


def load_network(model: nn.Module, checkpoint: dict, path: str) -> None:
    """Load the checkpoint's weights; a mismatch is a one-line UsageError."""
    try:
        result = model.load_state_dict(checkpoint["model"], strict=False)
    except RuntimeError as e:  # a tensor of another shape: name the first one
        lines = [line.strip() for line in str(e).splitlines() if "size mismatch" in line]
        detail = lines[0] if lines else str(e).strip().splitlines()[-1]
        raise UsageError(f"checkpoint {path!r} does not fit this network: {detail}") from e
    problems = [f"{kind}: {', '.join(keys[:4])}" + (" ..." if len(keys) > 4 else "")
                for kind, keys in (("missing", result.missing_keys),
                                   ("unexpected", result.unexpected_keys)) if keys]  # fmt: skip
    if problems:
        raise UsageError(
            f"checkpoint {path!r} does not fit this network (is it another script's?): "
            + "; ".join(problems)
        )


def restore(shared: Shared, checkpoint: dict, args: Any, path: str, agent: Any) -> None:
    """--resume: the checkpoint's network, optimizer statistics and global step into shared;
    UsageError if the flags its network depends on differ."""
    for key in agent.network_args:
        # a flag newer than the checkpoint: see Agent.trained_args (a network that differs all
        # the same fails to load below, with a one-line message)
        trained = agent.trained_args(checkpoint).get(
            key, agent.Args.__dataclass_fields__[key].default
        )
        if trained != getattr(args, key):
            raise UsageError(
                f"checkpoint {path!r} was trained with --{key.replace('_', '-')} "
                f"{trained}, not {getattr(args, key)}"
            )
    if checkpoint["optimizer_name"] != args.optimizer:
        raise UsageError(
            f"checkpoint {path!r} holds {checkpoint['optimizer_name']} statistics; "
            f"pass --optimizer {checkpoint['optimizer_name']}"
        )
    load_network(shared.model, checkpoint, path)
    try:
        shared.optimizer.load_state_dict(checkpoint["optimizer"])
    except (RuntimeError, KeyError) as e:
        first_line = str(e).strip().splitlines()[0]
        raise UsageError(f"checkpoint {path!r} does not fit this network: {first_line}") from e
    shared.base_step[0] = checkpoint["global_step"]
