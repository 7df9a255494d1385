"""The checkpoint file: one safetensors file (run folders name it checkpoint.pt, as ever).
Its tensors are flat, dense and declared (name, dtype, shape) in a header of bounded size;
everything else is one small JSON document in the header's metadata, validated against a
declared schema (`Document`: every field typed and bounded, unknown fields refused); the file
is sealed with the SHA-256 of its bytes. A generator's state is a tensor of its 37 bytes (every
value of which is a PCG64 state); a worker's Catch games are in the document, bounded by the
schema (a3c_runtime.catch_state). Such a file holds no code, no nesting, no views and no
shared or cyclic references, so none needs a check; what it can hold is checked here (the
header, the seal, the document) and by the gate (a3c_runtime.checkpoints: the tensor table
against the network the flags build) before a tensor is read, then by safetensors' own loader
(where each tensor's bytes lie) and here (their values). Written atomically. The seal guards
against accidents (a flipped bit, a truncated copy), not against someone: anyone can
recompute it."""

import contextlib
import hashlib
import json
import math
import os
import shlex
from pathlib import Path
from typing import Annotated, Any, Literal

import torch
from pydantic import ConfigDict, Field, ValidationError

from .catch_state import (
    CatchGames,
    Strict,
    generator_bytes,
    generator_state,
    loaded_games,
    stored_games,
)
from .flags import MAX_STEP, MAX_WORKERS, Flags, UsageError  # noqa: F401  (MAX_WORKERS: callers')

CHECKPOINT_FORMAT = "a3c-checkpoint-v4"  # safetensors with a declared document
OLDER_FORMATS = ("a3c-checkpoint-v3",)  # (and the torch zips before them): convert_checkpoint's
MAX_HEADER = 16 << 20  # bytes of the JSON header (tensor table and document), read before all
MAX_PENDING = 10_000
DTYPE_NAMES = {torch.float64: "F64", torch.float32: "F32", torch.bfloat16: "BF16",
               torch.float16: "F16", torch.int64: "I64", torch.int32: "I32", torch.int16: "I16",
               torch.int8: "I8", torch.uint8: "U8", torch.bool: "BOOL"}  # fmt: skip
SEAL = "0" * 64  # the seal's place in the header while the SHA-256 is computed


# ------------------------------------------------------------------------------------------------
# The schema: every field of the document with its type and bounds; nothing else is accepted
# ------------------------------------------------------------------------------------------------
Step = Annotated[int, Field(ge=0, le=MAX_STEP)]


class Document(Strict):
    """Everything of a checkpoint but its tensors."""

    format: Literal["a3c-checkpoint-v4"]
    script: Annotated[str, Field(max_length=4096)]
    global_step: Step
    wall_time: Annotated[float, Field(ge=0, le=1e12)]
    args: Flags
    pending_steps: Annotated[list[Step], Field(max_length=MAX_PENDING)]
    # each worker's Catch games (None: no env state, as on Atari), by id (below MAX_WORKERS)
    workers: dict[Annotated[str, Field(pattern=r"^(0|[1-9][0-9]{0,2}|10[01][0-9]|102[0-3])$")],
                  CatchGames | None]  # fmt: skip


class Entry(Strict):
    """A tensor in safetensors' header (where its bytes lie, safetensors' loader checks)."""

    dtype: Literal[tuple(DTYPE_NAMES.values())]  # type: ignore[valid-type]
    shape: Annotated[list[Annotated[int, Field(ge=0, le=1 << 40)]], Field(max_length=8)]
    data_offsets: tuple[int, int]


class Metadata(Strict):
    a3c: str
    sha256: Annotated[str, Field(pattern=r"^[0-9a-f]{64}$")]


TensorName = Annotated[str, Field(pattern=r"^(model|optimizer|pending/\d{1,5}|workers/\d{1,4})/"
                                          r"[A-Za-z0-9_./]{1,200}$")]  # fmt: skip


class Header(Strict):
    """safetensors' header: the document and the seal (metadata), each tensor by name."""

    model_config = ConfigDict(extra="allow")
    __pydantic_extra__: dict[TensorName, Entry]
    metadata: Metadata = Field(alias="__metadata__")


# ------------------------------------------------------------------------------------------------
# Writing
# ------------------------------------------------------------------------------------------------
def encode(raw: dict, checked: bool = True) -> bytes:
    """The file of a checkpoint's fields (save_checkpoint's `raw`; any other key goes into the
    document as it is). ValueError for what the format cannot hold: a view of more than its
    storage, a worker state of another form, a document the schema refuses (checked=False, for
    tests: written as it is); safetensors' RuntimeError for tensors sharing memory."""
    tensors = {f"model/{k}": v for k, v in raw["model"].items()}
    for key, value in raw["optimizer"].items():
        for i, tensor in enumerate(value if isinstance(value, list) else [value]):
            tensors[f"optimizer/{key}" + (f"/{i}" if isinstance(value, list) else "")] = tensor
    for k, (_, theta) in enumerate(raw["pending_evaluations"]):
        tensors.update({f"pending/{k}/{name}": tensor for name, tensor in theta.items()})
    workers = {}
    for worker_id, parts in raw["workers"].items():
        generator, env, frames, *carried = parts
        prefix, games = f"workers/{worker_id}", None
        own = {"frames": frames, "generator": generator_bytes(generator["bit_generator"])}
        if env is not None:  # Catch's games: their stacks are the frames
            games, catch = stored_games(env["env"], frames)
            own.update(catch)
        for j, tensor in enumerate(carried[0] if carried else ()):
            own[f"lstm/{j}"] = tensor  # (an LSTM's carried state)
        tensors.update({f"{prefix}/{name}": tensor for name, tensor in own.items()})
        workers[str(worker_id)] = games
    for name, tensor in tensors.items():  # (before .contiguous(), which would copy a view)
        dense = tensor.layout == torch.strided and tensor.dtype in DTYPE_NAMES
        if not dense or tensor.numel() * tensor.element_size() > storage_bytes(tensor):
            raise ValueError(f"{name} is not a dense tensor of a safetensors dtype")
    parts = ("model", "optimizer", "pending_evaluations", "workers", "format", "pending_steps")
    document = {"format": CHECKPOINT_FORMAT, **{k: v for k, v in raw.items() if k not in parts},
                "pending_steps": [step for step, _ in raw["pending_evaluations"]],
                "workers": workers}  # fmt: skip
    if checked:  # (before json.dumps, which would walk whatever a field holds)
        Document.model_validate(document)
    return sealed({k: v.detach().cpu().contiguous() for k, v in tensors.items()}, document)


def sealed(tensors: dict[str, torch.Tensor], document: dict) -> bytes:
    """The safetensors file of tensors and the document, with the SHA-256 of its bytes (those
    of the seal's place zeros) in the header."""
    import safetensors.torch

    text = json.dumps(document, separators=(",", ":"))
    data = safetensors.torch.save(tensors, metadata={"a3c": text, "sha256": SEAL})
    end = 8 + int.from_bytes(data[:8], "little")
    digest = seal_digest(data, SEAL)
    return data[:end].replace(seal_field(SEAL), seal_field(digest), 1) + data[end:]


def seal_digest(data: bytes, seal: str) -> str:
    """The SHA-256 that a file's seal stands for: of its bytes with the seal's place zeroed (its
    first `seal` field, in the header), hashed around it rather than copied (a 16 MB copy costs
    as much as the hash)."""
    view, field = memoryview(data), seal_field(seal)
    at = data.find(field)
    if at < 0:
        return hashlib.sha256(data).hexdigest()
    digest = hashlib.sha256(view[:at])
    digest.update(seal_field(SEAL))
    digest.update(view[at + len(field) :])
    return digest.hexdigest()


def seal_field(digest: str) -> bytes:
    return f'"sha256":"{digest}"'.encode()


def storage_bytes(tensor: torch.Tensor) -> int:
    return tensor.untyped_storage().nbytes() - tensor.storage_offset() * tensor.element_size()


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


def convert_command(path: str) -> str:
    """The command that converts a checkpoint of the older format that its owner trusts."""
    return shlex.join(["python", "-m", "a3c_tools.convert_checkpoint", path])


def read_checkpoint(
    path: str, flag: str | None = None, data: bytes | None = None
) -> tuple[dict, dict[str, Entry], bytes]:
    """(the document, the tensor table, the bytes) of the checkpoint at path (or of its bytes,
    `data`): its header bounded and validated, its seal verified, its document validated by the
    schema; no tensor read (where their bytes lie, read_tensors' loader checks). Else a
    one-line UsageError."""
    if data is None:
        check_checkpoint_path(path, flag)
        try:
            data = Path(path).read_bytes()  # read once: what is verified is what is loaded
        except OSError as e:
            raise UsageError(f"cannot read checkpoint {path!r}: {e.strerror or e}") from e
    if data[:2] == b"PK":  # a zip: torch.save's, the format before safetensors
        raise older_format(path, "a torch zip")
    size = int.from_bytes(data[:8], "little")
    try:
        if size > min(MAX_HEADER, len(data) - 8):
            raise ValueError(f"its header declares {size:,} bytes (the file has {len(data):,})")
        header = Header.model_validate_json(data[8 : 8 + size])
    except ValueError as e:  # (pydantic's ValidationError among them)
        raise UsageError(f"checkpoint {path!r} is corrupt or not a checkpoint: "
                         f"{problem_of(e)}") from None  # fmt: skip
    seal = header.metadata.sha256  # (its place zeroed, as sealed() hashed it)
    if seal != seal_digest(data, seal):
        raise UsageError(f"checkpoint {path!r} is corrupt: its bytes do not match the SHA-256 "
                         "it was written with")  # fmt: skip
    try:
        document = Document.model_validate_json(header.metadata.a3c).model_dump(exclude_unset=True)
    except ValidationError as e:
        tag = e.errors()[0]["input"] if e.errors()[0]["loc"] == ("format",) else None
        malformed = UsageError(f"checkpoint {path!r} is malformed: {problem_of(e)}")
        raise older_format(path, tag) if tag in OLDER_FORMATS else malformed from None
    return document, header.__pydantic_extra__, data


class OlderFormat(UsageError):
    """A checkpoint of an older format: a3c_tools.convert_checkpoint converts it."""


def older_format(path: str, kind: str) -> OlderFormat:
    """The refusal of a checkpoint of an older format, naming the command that converts it."""
    return OlderFormat(f"checkpoint {path!r} is of the older format ({kind}), which is not loaded; "
                      f"if you trust it, convert it: {convert_command(path)}")  # fmt: skip


def problem_of(error: Exception) -> str:
    """One line of a parse or validation error: where, and what."""
    if isinstance(error, ValidationError):
        first = error.errors()[0]
        where = "/".join(str(part) for part in first["loc"])
        return (f"its {where}: " if where else "") + first["msg"].split(" '^")[0]
    return (str(error).strip().splitlines() or [type(error).__name__])[0][:200]


def read_tensors(data: bytes, document: dict, path: str) -> dict[str, Any]:
    """The tensors of a checkpoint's bytes (read_checkpoint's; their table already matched the
    network's), loaded by safetensors (which refuses bytes that are not where the table puts
    them) and checked (finite: NaN or inf is a run that diverged; mean squares not negative;
    Catch's start draws in [0, 1)), in the form the runtime holds them (runtime_form)."""
    import safetensors.torch

    try:
        tensors = safetensors.torch.load(data)
    except safetensors.SafetensorError as e:
        raise UsageError(f"checkpoint {path!r} is corrupt: its tensors are not where its header "
                         f"puts them ({problem_of(e)})") from None  # fmt: skip
    squares = ("optimizer/square_avg/", "optimizer/exp_avg_sq/", "optimizer/step")
    for name, tensor in tensors.items():
        # (aminmax carries a NaN through: one pass, no mask, 40x isfinite's speed on the CPU)
        floating = tensor.is_floating_point() and tensor.numel()  # (WW: 0 where maps, say)
        if floating and not all(map(math.isfinite, torch.aminmax(tensor))):
            raise UsageError(f"checkpoint {path!r}: its {name} holds NaN or inf (the run diverged)")
        if name.startswith(squares) and bool((tensor < 0).any()):
            raise UsageError(f"checkpoint {path!r}: its optimizer statistic {name} is negative")
        if name.endswith("/starts") and not bool(((tensor >= 0) & (tensor < 1)).all()):
            raise UsageError(f"checkpoint {path!r}: its {name} holds a draw outside [0, 1)")
    return runtime_form(tensors, document)


def runtime_form(tensors: dict[str, torch.Tensor], document: dict) -> dict[str, Any]:
    """A checkpoint's tensors and document (read_tensors') in the form the runtime holds them:
    `model`, `optimizer`, `workers` (each worker's state as a3c_runtime.snapshots.saved_state
    gives it) and `pending_evaluations`: encode's flattening undone."""
    model = {n.removeprefix("model/"): t for n, t in tensors.items() if n.startswith("model/")}
    optimizer: dict[str, Any] = {}
    for name in sorted((n for n in tensors if n.startswith("optimizer/")), key=natural):
        stat, _, index = name.removeprefix("optimizer/").partition("/")
        if index:
            optimizer.setdefault(stat, []).append(tensors[name])
        else:
            optimizer[stat] = tensors[name]
    pending = [(step, {n: tensors[f"pending/{k}/{n}"] for n in model})
               for k, step in enumerate(document["pending_steps"])]  # fmt: skip
    workers = {}
    for worker_id, games in document["workers"].items():
        prefix = f"workers/{worker_id}/"
        own = {n.removeprefix(prefix): t for n, t in tensors.items() if n.startswith(prefix)}
        env, frames = None, own["frames"]
        if games is not None:  # Catch's games, in the form catch_env's get_state gives
            state, frames = loaded_games(games, own)
            env = {"env": state}
        carried = tuple(own[n] for n in sorted(own, key=natural) if n.startswith("lstm/"))
        parts = [{"bit_generator": generator_state(own["generator"])}, env,
                 frames] + ([carried] if carried else [])  # fmt: skip
        workers[int(worker_id)] = parts
    return {
        "model": model,
        "optimizer": optimizer,
        "workers": workers,
        "pending_evaluations": pending,
    }


def natural(name: str) -> list:
    return [int(part) if part.isdigit() else part for part in name.split("/")]


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
