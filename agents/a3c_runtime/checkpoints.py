"""Checkpoints: saved (save_checkpoint, in the format of a3c_runtime.checkpoint_file:
safetensors with a declared document, sealed, written atomically); the gate (a checkpoint read
once, every field checked, handed on as a `Checkpoint` record; nothing downstream reads a raw
field); restoring for --resume. A checkpoint is someone else's data: a field that becomes a
script, an env, a number of processes or a size is checked against what the project offers,
and its tensors' names, dtypes and shapes against those of the network its validated flags
build (on torch's meta device: nothing allocated) before a tensor is read. Checkpoints of the
older format (a torch zip) are read only by python -m a3c_tools.convert_checkpoint."""

import functools
import re
import typing
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path
from typing import Any

import torch
import torch.nn as nn
from pydantic import ConfigDict, TypeAdapter, ValidationError
from typing_extensions import TypedDict

from catch_env.catch import START_BUFFER

from .catch_state import PCG64_BYTES
from .checkpoint_file import (  # noqa: F401  (the names callers import from here)
    CHECKPOINT_FORMAT,
    DTYPE_NAMES,
    MAX_WORKERS,
    PARTIAL_SUFFIX,
    Entry,
    WriteFailed,
    check_checkpoint_path,
    convert_command,
    encode,
    partial_path,
    problem_of,
    read_checkpoint,
    read_tensors,
    write_atomically,
)
from .flags import OBSERVATION_SHAPE, VALID_ENVS, UsageError, probe_env
from .hogwild import Shared

# a script a checkpoint may name: agents/a3c_*.py or agents/future_work/a3c_*.py, by file name
# ("" before the name was stored); never a path elsewhere
SCRIPT_NAME = re.compile(r"(future_work/)?a3c_[A-Za-z0-9_]+\.py")


def save_checkpoint(
    path: Path,
    shared: Shared | None,
    args: Any,
    wall_time: float,
    script: str = "",
    snapshot: dict | None = None,
) -> None:
    """Write atomically (temp file + rename) so that a crash never leaves a corrupt checkpoint.
    Of theta, the optimizer statistics and the global step as they are in `shared`, or as a
    worker copied them at a checkpoint mark (`snapshot`: model, optimizer, global_step; shared
    None: a batched run's); either may add what an exact resume needs (a3c_runtime.snapshots):
    `workers`, each worker's state (snapshots.saved_state), and `pending_evaluations`, the
    (step, theta) evaluations not taken."""
    snapshot = snapshot or {}
    if "model" not in snapshot:  # theta, its statistics and the step as they are in shared
        snapshot = {**snapshot, "model": shared.model.state_dict(),
                    "optimizer": shared.optimizer.state_dict(),
                    "global_step": shared.global_step()}  # fmt: skip
    raw = {
        "script": script,
        "model": snapshot["model"],
        "optimizer": snapshot["optimizer"],
        "global_step": snapshot["global_step"],
        "wall_time": wall_time,
        "args": asdict(args),
        "workers": snapshot.get("workers", {}),
        "pending_evaluations": snapshot.get("pending_evaluations", []),
    }
    write_atomically(path, encode(raw))  # encoded first: a failed write is the OS's own error


@dataclass(frozen=True)
class Checkpoint:
    """A checkpoint that passed the gate (open_checkpoint; load_checkpoint for a script): every
    field checked. `flags` is the script's Args of the run, and the tensors (model, optimizer,
    workers' states, pending evaluations) are read, only after load_checkpoint (for_agent);
    `run_folder` is the folder of the run that wrote it (the checkpoint's own)."""

    path: str
    script: str
    env: str
    args: dict[str, Any]
    global_step: int
    wall_time: float
    run_folder: Path
    model: dict[str, torch.Tensor] = field(default_factory=dict)
    optimizer: dict = field(default_factory=dict)
    workers: dict[int, list] = field(default_factory=dict)
    pending_evaluations: list[tuple[int, dict]] = field(default_factory=list)
    flags: Any = None
    document: dict = field(default_factory=dict, repr=False)
    table: dict[str, Entry] = field(default_factory=dict, repr=False)
    data: bytes = field(default=b"", repr=False)


def open_checkpoint(path: str, flag: str | None = None, data: bytes | None = None) -> Checkpoint:
    """The gate: the checkpoint at path read once (read_checkpoint) and checked: the script a
    name of agents/ or agents/future_work/, the env an id the scripts accept (its flags' counts
    and sizes are the schema's: flags.Flags). Else a one-line UsageError naming what
    is wrong. (`data`: the file's
    bytes, read already.)"""
    raw, table, data = read_checkpoint(path, flag, data)
    if raw["script"] and not SCRIPT_NAME.fullmatch(raw["script"]):
        raise UsageError(
            f"checkpoint {path!r} names the script {raw['script']!r}, not an agent script "
            "(agents/a3c_*.py or agents/future_work/a3c_*.py by file name)"
        )
    env = raw["args"].get("env")
    problem = "no env" if not isinstance(env, str) else env_problem(env)
    if problem is not None:
        raise UsageError(f"checkpoint {path!r} holds the env {env!r}: {problem}")
    fields = {key: raw[key] for key in ("script", "args", "global_step", "wall_time")}
    folder = Path(path).resolve().parent
    return Checkpoint(
        path, env=env, run_folder=folder, document=raw, table=table, data=data, **fields
    )


def env_problem(env_id: str) -> str | None:
    """Why the scripts do not accept env_id (Catch-v0 or an ALE id; never `module:id`, which
    Gymnasium would import), or None. Looks the id up without making the env."""
    import gymnasium as gym

    from catch_env import CATCH_ENTRY_POINT  # (and registers Catch-v0)
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


def load_checkpoint(path: str, agent: Any, flag: str | None = None) -> Checkpoint:
    """The gate for a script: a checkpoint of this script (open_checkpoint, then for_agent), or
    a one-line UsageError saying what is wrong with it."""
    return for_agent(open_checkpoint(path, flag), agent)


def for_agent(checkpoint: Checkpoint, agent: Any) -> Checkpoint:
    """A checkpoint that passed open_checkpoint, checked as agent's: written by agent.script
    (or before the name was stored), its flags of the script's types, its tensors those of the
    network its flags build; with `flags` set to the run's Args and its tensors read.
    UsageError otherwise."""
    path, script, hints = checkpoint.path, checkpoint.script, typing.get_type_hints(agent.Args)
    if script and script != agent.script:
        raise UsageError(
            f"checkpoint {path!r} was written by {script}, not {agent.script}: "
            f"use python agents/{script}"
        )
    trained = {k: v for k, v in agent.trained_args(checkpoint).items() if k in hints}
    try:
        flags = agent.Args(**flags_type(agent.Args).validate_python(trained))
    except ValidationError as e:
        raise UsageError(f"checkpoint {path!r} is malformed: its flag "
                         f"{problem_of(e).removeprefix('its ')}") from None  # fmt: skip
    problem = fit_problem(expected_table(agent, flags, checkpoint), checkpoint.table)
    if problem is not None:  # before a tensor is read
        raise UsageError(f"checkpoint {path!r} does not fit this network{problem}")
    tensors = read_tensors(checkpoint.data, checkpoint.document, path)
    return replace(checkpoint, **tensors, data=b"", flags=flags)


def expected_table(agent: Any, flags: Any, checkpoint: Checkpoint) -> dict[str, tuple]:
    """The (dtype, shape) of each tensor a checkpoint of these flags holds: those of the network
    they build, on torch's meta device (nothing allocated), its optimizer statistics, each
    pending evaluation's network and each worker's frames, Catch state and LSTM state."""
    from catch_env.wrappers import is_atari

    path, envs = checkpoint.path, flags.envs_per_worker
    try:
        with torch.device("meta"):
            network = agent.network(probe_env(agent.make_env, checkpoint.env), flags)
            carried = network.initial_state(envs) if hasattr(network, "initial_state") else ()
    except (UsageError, RuntimeError, ValueError, TypeError, OverflowError, MemoryError) as e:
        raise UsageError(
            f"checkpoint {path!r}: its flags build no network ({problem_of(e)})"
        ) from None
    model = {k: (DTYPE_NAMES.get(v.dtype), tuple(v.shape)) for k, v in network.state_dict().items()}
    table = {f"model/{k}": v for k, v in model.items()}
    params = [(DTYPE_NAMES.get(p.dtype), tuple(p.shape)) for p in network.parameters()]
    adam = flags.optimizer == "adam"
    for stat in ("exp_avg", "exp_avg_sq") if adam else ("square_avg",):
        table.update({f"optimizer/{stat}/{i}": p for i, p in enumerate(params)})
    if adam:
        table["optimizer/step_count"] = ("F64", (1,))
    for k in range(len(checkpoint.document["pending_steps"])):
        table.update({f"pending/{k}/{name}": v for name, v in model.items()})
    for worker_id, games in checkpoint.document["workers"].items():
        prefix = f"workers/{worker_id}"
        table[f"{prefix}/frames"] = ("U8", (envs, *OBSERVATION_SHAPE))
        table[f"{prefix}/generator"] = ("U8", (PCG64_BYTES,))
        table.update({f"{prefix}/lstm/{j}": (DTYPE_NAMES.get(s.dtype), tuple(s.shape))
                      for j, s in enumerate(carried)})  # fmt: skip
        if games is not None:  # Catch's: the stacks' older frames as bits, the start draws
            if is_atari(checkpoint.env) or any(len(values) != envs for values in games.values()):
                raise UsageError(f"checkpoint {path!r} is malformed: worker {worker_id}'s env "
                                 f"state is not that of {envs} Catch envs")  # fmt: skip
            frames = (envs, OBSERVATION_SHAPE[0] - 1, *OBSERVATION_SHAPE[1:])
            table.update({f"{prefix}/frames": ("BOOL", frames),
                          f"{prefix}/starts": ("F64", (envs, START_BUFFER, 3)),
                          f"{prefix}/generators": ("U8", (envs, PCG64_BYTES))})  # fmt: skip
    return table


def fit_problem(expected: dict[str, tuple], table: dict[str, Entry]) -> str | None:
    """The first tensor (by name: the network's first) in which the tensor table differs from
    the expected one, and how; or None."""
    have = {name: (entry.dtype, tuple(entry.shape)) for name, entry in table.items()}
    differ = sorted(n for n in expected.keys() | have.keys() if expected.get(n) != have.get(n))
    name = differ[0] if differ else None
    hint = "" if name in have and name in expected else " (is it another script's?)"
    return name and f"{hint}: {name}: {have.get(name, 'missing')} in it, {expected.get(name)} here"


@functools.cache
def flags_type(args: type) -> TypeAdapter:
    """A script's flags by name, each of its annotation's type (Annotated's metadata aside), as
    pydantic's strict mode checks them: a TypedDict of the Args' annotations."""
    flags = TypedDict(args.__name__, typing.get_type_hints(args), total=False)
    flags.__pydantic_config__ = ConfigDict(strict=True)
    return TypeAdapter(flags)


def checkpoint_step(path: Path, agent: Any = None) -> int | None:
    """The global step of a checkpoint that passes the gate (open_checkpoint; load_checkpoint
    as agent's, given one), else None."""
    try:
        checkpoint = open_checkpoint(str(path))
        return (checkpoint if agent is None else for_agent(checkpoint, agent)).global_step
    except UsageError:
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
    if checkpoint.flags.optimizer != args.optimizer:
        raise UsageError(
            f"checkpoint {path!r} holds {checkpoint.flags.optimizer} statistics; "
            f"pass --optimizer {checkpoint.flags.optimizer}"
        )
    load_network(shared.model, checkpoint, path)
    try:
        shared.optimizer.load_state_dict(checkpoint.optimizer)
    except (RuntimeError, KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
        first_line = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise UsageError(f"checkpoint {path!r} does not fit this network: {first_line}") from e
    shared.base_step[0] = checkpoint.global_step
