"""Checkpoints: written atomically (a temp file, flushed to disk, then a rename) so that a crash
or a full disk never leaves a corrupt one or a partial file, and sealed with a SHA-256 of their
bytes; verified and validated on load (every zip member's CRC, and the seal), so that a missing,
changed, truncated or foreign checkpoint is a one-line UsageError before anything uses it;
restored into the shared network and optimizer for --resume."""

from __future__ import annotations

import contextlib
import hashlib
import io
import os
import struct
import zipfile
from dataclasses import asdict
from pathlib import Path
from typing import Any

import torch
import torch.nn as nn

from .flags import UsageError
from .hogwild import Shared

CHECKPOINT_FORMAT = "a3c-checkpoint-v1"  # "script" was added compatibly: older ones lack it
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
    may add what an exact resume needs (a3c_runtime.snapshots): `workers`, each worker's pickled
    state, and `pending_evaluations`, the (step, theta) evaluations not taken yet."""
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
    """The zip archive torch.save wrote, with the SHA-256 of its bytes as the zip's comment (as
    it is if torch ever writes another layout: its CRCs are still checked)."""
    if archive[-22:-18] != END_OF_ARCHIVE or archive[-2:] != b"\x00\x00":
        return archive
    length = len(SEAL_PREFIX) + hashlib.sha256().digest_size * 2
    head = archive[:-2] + struct.pack("<H", length)  # the comment's length is sealed too
    return head + SEAL_PREFIX + hashlib.sha256(head).hexdigest().encode()


def verify_checkpoint(data: bytes) -> str | None:
    """What is wrong with a checkpoint's bytes, or None if nothing: a member whose CRC fails,
    an archive that is no zip (truncated, another format), a seal that does not match its
    bytes. Checkpoints from before the seal (no zip comment) are checked by CRC alone."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            bad_member = archive.testzip()  # reads every member, checking its CRC
            comment = archive.comment
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, ValueError) as e:
        return f"not a whole zip archive ({e})"
    if bad_member is not None:
        return f"{bad_member} fails its CRC check"
    if comment:
        head = data[: len(data) - len(comment)]
        if comment != SEAL_PREFIX + hashlib.sha256(head).hexdigest().encode():
            return "its bytes do not match the SHA-256 it was written with"
    return None


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
    """The global step of a checkpoint that verifies and loads, else None."""
    try:
        data = Path(path).read_bytes()
        if verify_checkpoint(data) is not None:
            return None
        checkpoint = torch.load(io.BytesIO(data), map_location="cpu", weights_only=False)
        return int(checkpoint["global_step"])
    except Exception:
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
    """Load a checkpoint of this script, or raise UsageError saying what is wrong with it. Its
    bytes are verified before torch reads them: a changed or truncated file is refused."""
    check_checkpoint_path(path, flag)
    try:
        data = Path(path).read_bytes()  # read once: what is verified is what is loaded
    except OSError as e:
        raise UsageError(f"cannot read checkpoint {path!r}: {e.strerror or e}") from e
    problem = verify_checkpoint(data)
    if problem is not None:
        raise UsageError(f"checkpoint {path!r} is corrupt: {problem}")
    try:
        checkpoint = torch.load(io.BytesIO(data), map_location="cpu", weights_only=False)
    except Exception as e:
        detail = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise UsageError(f"checkpoint {path!r} is corrupt or not a torch file: {detail}") from e
    if not isinstance(checkpoint, dict) or checkpoint.get("format") != CHECKPOINT_FORMAT:
        raise UsageError(f"{path!r} is not a checkpoint written by this script")
    script = checkpoint.get("script")  # absent before it was stored
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
