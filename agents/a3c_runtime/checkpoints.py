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
import math
import os
import pickle
import re
import shlex
import struct
import types
import typing
import zipfile
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import torch
import torch.nn as nn

from .flags import VALID_ENVS, UsageError
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
            # torch stores its members uncompressed: members that declare more bytes than the
            # file holds are a compressed archive's, refused before anything is inflated
            declared = sum(member.file_size for member in archive.infolist())
            if declared > len(data):
                return (
                    f"its members declare {declared:,} bytes, more than the {len(data):,} of the "
                    "file (torch stores them uncompressed)"
                )
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


PARTIAL_SUFFIX = ".a3c-partial"  # a name no user's file has: a run removes only its own


def partial_path(path: Path) -> Path:
    """The temp file write_atomically writes path's new content into before the rename."""
    return path.with_name(path.name + PARTIAL_SUFFIX)


def write_atomically(path: Path, data: bytes | memoryview) -> None:
    """path's new content, all or nothing: a temp file beside it, flushed to disk, renamed over
    it. On failure the temp file is removed and the old file is untouched: WriteFailed."""
    tmp = partial_path(path)
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


def checkpoint_step(path: Path, agent: Any = None) -> int | None:
    """The global step of a checkpoint that passes the gate (open_checkpoint; load_checkpoint
    as agent's, given one), else None."""
    try:
        checkpoint = open_checkpoint(str(path))
        return (checkpoint if agent is None else for_agent(checkpoint, agent)).global_step
    except UsageError:
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


# ------------------------------------------------------------------------------------------------
# The gate: a checkpoint is read once, every field checked, and handed on as a Checkpoint record;
# nothing downstream reads a raw field. A checkpoint is someone else's data: a field that becomes
# a script, an env, a number of processes or a size is checked against what the project offers.
# ------------------------------------------------------------------------------------------------
# a script a checkpoint may name: agents/a3c_*.py or agents/future_work/a3c_*.py, by file name
# ("" before the name was stored); never a path elsewhere
SCRIPT_NAME = re.compile(r"(future_work/)?a3c_[A-Za-z0-9_]+\.py")
# what a checkpoint's flags may ask of this machine, beyond the flags' own checks (flags.py)
FLAG_BOUNDS = {
    "num_workers": 1024,  # processes
    "envs_per_worker": 4096,
    "eval_episodes": 10_000,  # envs, one per episode
    "t_max": 100_000,
    "total_timesteps": 10**13,
    "eval_interval": 10**13,
    "checkpoint_interval": 10**13,
}
FIELDS = {  # each field a checkpoint has, and the type it must be
    "format": str, "script": str, "network": str, "model": dict, "optimizer": dict,
    "optimizer_name": str, "global_step": int, "wall_time": (int, float), "args": dict,
    "workers": dict, "pending_evaluations": (list, tuple),
}  # fmt: skip


@dataclass(frozen=True)
class Checkpoint:
    """A checkpoint that passed the gate (open_checkpoint; load_checkpoint for a script): every
    field checked. `flags` is the script's Args of the run (None before load_checkpoint);
    `run_folder` is the folder of the run that wrote it (the checkpoint's own)."""

    path: str
    script: str
    env: str
    args: dict[str, Any]
    global_step: int
    wall_time: float
    optimizer_name: str
    model: dict[str, torch.Tensor]
    optimizer: dict
    workers: dict[int, list]
    pending_evaluations: list[tuple[int, dict]]
    run_folder: Path
    flags: Any = None


def open_checkpoint(path: str, flag: str | None = None) -> Checkpoint:
    """The gate: the checkpoint at path read once (read_checkpoint) and checked: every field
    there with its type, the script a name of agents/ or agents/future_work/, the env an id the
    scripts accept, its flags' sizes within FLAG_BOUNDS, a network of finite real weights.
    Else a one-line UsageError naming what is wrong."""
    return checked(read_checkpoint(path, flag), path)


def checked(raw: dict, path: str) -> Checkpoint:
    """open_checkpoint's checks of a checkpoint read safely from path (read_checkpoint)."""
    problem = malformed(raw)
    if problem is not None:
        raise UsageError(f"checkpoint {path!r} is malformed: {problem}")
    if raw["script"] and not SCRIPT_NAME.fullmatch(raw["script"]):
        raise UsageError(
            f"checkpoint {path!r} names the script {raw['script']!r}, not an agent script "
            "(agents/a3c_*.py or agents/future_work/a3c_*.py by file name)"
        )
    env = raw["args"].get("env")
    problem = env_problem(env)
    if problem is not None:
        raise UsageError(f"checkpoint {path!r} holds the env {env!r}: {problem}")
    problem = size_problem(raw["args"])
    if problem is not None:
        raise UsageError(f"checkpoint {path!r} asks for {problem}")
    for part, tensors in (("network", raw["model"]),
                          *(("network of a pending evaluation", theta)
                            for _, theta in raw["pending_evaluations"])):  # fmt: skip
        problem = weights_problem(tensors)
        if problem is not None:
            raise UsageError(f"checkpoint {path!r}: the {part} {problem}")
    return Checkpoint(
        path=path, script=raw["script"], env=env, args=raw["args"],
        global_step=raw["global_step"], wall_time=float(raw["wall_time"]),
        optimizer_name=raw["optimizer_name"], model=raw["model"], optimizer=raw["optimizer"],
        workers=raw["workers"],
        pending_evaluations=[(step, theta) for step, theta in raw["pending_evaluations"]],
        run_folder=Path(path).resolve().parent,
    )  # fmt: skip


def malformed(raw: dict) -> str | None:
    """What is missing or of the wrong type in a checkpoint's fields, or None."""
    for key, kind in FIELDS.items():
        if key not in raw:
            return f"it has no {key!r}"
        value = raw[key]
        if not isinstance(value, kind) or isinstance(value, bool):
            return f"its {key!r} is a {type(value).__name__}"
    if raw["global_step"] < 0 or not (0 <= raw["wall_time"] < math.inf):
        return "its 'global_step' or 'wall_time' is negative or not finite"
    if not all(isinstance(k, str) for k in raw["args"]) or not isinstance(
        raw["args"].get("env"), str
    ):
        return "its 'args' are not flags by name with an 'env'"
    if not raw["model"] or not all(
        isinstance(k, str) and torch.is_tensor(v) for k, v in raw["model"].items()
    ):
        return "its 'model' is not a network's tensors by name"
    if not all(isinstance(worker_id, int) and isinstance(states, (list, tuple))
               for worker_id, states in raw["workers"].items()):  # fmt: skip
        return "its 'workers' are not each worker's state by its number"
    shapes = {name: tensor.shape for name, tensor in raw["model"].items()}
    for request in raw["pending_evaluations"]:
        if not (isinstance(request, (list, tuple)) and len(request) == 2
                and isinstance(request[0], int) and isinstance(request[1], dict)
                and all(torch.is_tensor(v) for v in request[1].values())
                and {k: v.shape for k, v in request[1].items()} == shapes):  # fmt: skip
            return "its 'pending_evaluations' are not (step, its network) pairs"
    complex_part = next((key for key in raw if any_complex(raw[key])), None)
    if complex_part is not None:  # loaded into a real network, its imaginary part would be lost
        return f"its {complex_part!r} holds a complex-valued tensor"
    return None


def any_complex(value: Any) -> bool:
    """Whether a complex tensor is anywhere in value (through dicts, lists and tuples)."""
    if torch.is_tensor(value):
        return value.is_complex()
    if isinstance(value, dict):
        return any(any_complex(item) for item in value.values())
    if isinstance(value, (list, tuple)):
        return any(any_complex(item) for item in value)
    return False


def env_problem(env_id: str) -> str | None:
    """Why the scripts do not accept env_id (Catch-v0 or an ALE id; never `module:id`, which
    Gymnasium would import), or None. Looks the id up without making the env."""
    import gymnasium as gym

    import catch_env  # noqa: F401  (registers Catch-v0)
    from catch_env.wrappers import ATARI_ENTRY_POINT, is_atari

    if ":" in env_id:
        return f"a module to import, not an env id; valid: {VALID_ENVS}"
    try:
        atari = is_atari(env_id)  # registers the ALE ids first
    except ImportError as e:
        return str(e)
    except gym.error.Error:
        return f"an unknown env id; valid: {VALID_ENVS}"
    if not atari and gym.spec(env_id).entry_point not in (CATCH_ENTRY_POINT, ATARI_ENTRY_POINT):
        return f"not an env of the scripts; valid: {VALID_ENVS}"
    return None


CATCH_ENTRY_POINT = "catch_env.catch:CatchEnv"


def size_problem(args: dict) -> str | None:
    """`--flag VALUE (valid: ...)` for a flag of args that names a count or size out of
    FLAG_BOUNDS (or is not a whole number), or None."""
    for name, bound in FLAG_BOUNDS.items():
        if name not in args:
            continue  # a flag newer than the checkpoint: its default
        value = args[name]
        if not isinstance(value, int) or isinstance(value, bool) or not 1 <= value <= bound:
            return f"--{name.replace('_', '-')} {value!r} (valid: 1 to {bound:,})"
    return None


def weights_problem(tensors: dict) -> str | None:
    """What is wrong with a network's tensors: one not finite (NaN or inf: a run that
    diverged), or None."""
    for name, tensor in tensors.items():
        if tensor.is_floating_point() and not bool(torch.isfinite(tensor).all()):
            return f"has non-finite weights (NaN or inf in {name}: the run diverged)"
    return None


def load_checkpoint(path: str, agent: Any, flag: str | None = None) -> Checkpoint:
    """The gate for a script: a checkpoint of this script (open_checkpoint, then for_agent), or
    a one-line UsageError saying what is wrong with it."""
    return for_agent(open_checkpoint(path, flag), agent)


def for_agent(checkpoint: Checkpoint, agent: Any) -> Checkpoint:
    """A checkpoint that passed open_checkpoint, checked as agent's: written by agent.script
    (or before the name was stored), its flags of the script's types; with `flags` set to the
    run's Args. UsageError otherwise."""
    path, script = checkpoint.path, checkpoint.script
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
    trained = agent.trained_args(checkpoint)
    hints = typing.get_type_hints(agent.Args)
    for name, value in trained.items():
        if name in hints and not of_type(value, hints[name]):
            kind = getattr(hints[name], "__name__", str(hints[name]))
            raise UsageError(
                f"checkpoint {path!r} is malformed: its --{name.replace('_', '-')} {value!r} is "
                f"not {kind}"
            )
    known = {f.name for f in fields(agent.Args)}
    try:
        flags = agent.Args(**{k: v for k, v in trained.items() if k in known})
    except (TypeError, ValueError) as e:
        raise UsageError(f"checkpoint {path!r} has other flags than this script: {e}") from e
    return replace(checkpoint, flags=flags)


def of_type(value: Any, hint: Any) -> bool:
    """Whether value is of the type a flag's annotation names (bool, int, float, str, None,
    a Literal, a union of them); an annotation of another kind is not checked."""
    origin = typing.get_origin(hint)
    if origin is typing.Annotated:
        return of_type(value, typing.get_args(hint)[0])
    if origin is typing.Literal:
        return any(type(value) is type(c) and value == c for c in typing.get_args(hint))
    if origin in (typing.Union, types.UnionType):
        return any(of_type(value, option) for option in typing.get_args(hint))
    if hint is type(None):
        return value is None
    if hint is bool:
        return isinstance(value, bool)
    if hint is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if hint is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if hint is str:
        return isinstance(value, str)
    return True


def moved_script(checkpoint: Checkpoint) -> tuple[str, str, Any] | None:
    """(the future-work script, the flag, its value) of a checkpoint that a thesis script wrote
    with a chapter-8 flag set (MOVED_FLAGS), else None."""
    for (flag, value), owner in MOVED_FLAGS.get(checkpoint.script, {}).items():
        if checkpoint.args.get(flag) == value:
            return owner, flag, value
    return None


def load_network(model: nn.Module, checkpoint: Checkpoint, path: str | None = None) -> None:
    """Load the checkpoint's weights; a mismatch is a one-line UsageError."""
    path = checkpoint.path if path is None else path
    try:
        result = model.load_state_dict(checkpoint.model, strict=False)
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


def restore(shared: Shared, checkpoint: Checkpoint, args: Any, path: str, agent: Any) -> None:
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
    if checkpoint.optimizer_name != args.optimizer:
        raise UsageError(
            f"checkpoint {path!r} holds {checkpoint.optimizer_name} statistics; "
            f"pass --optimizer {checkpoint.optimizer_name}"
        )
    load_network(shared.model, checkpoint, path)
    try:
        shared.optimizer.load_state_dict(checkpoint.optimizer)
    except (RuntimeError, KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
        first_line = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise UsageError(f"checkpoint {path!r} does not fit this network: {first_line}") from e
    shared.base_step[0] = checkpoint.global_step
