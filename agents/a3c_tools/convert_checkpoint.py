"""A checkpoint from before checkpoints were safe to load, converted into the safe form, on its
owner's explicit request:

    python -m a3c_tools.convert_checkpoint runs/<run>/checkpoint.pt

The agent scripts and the tools load a checkpoint only with `torch.load(weights_only=True)`,
which builds tensors, numbers, strings, lists, tuples and dicts and runs no code; they refuse
an older checkpoint (format v1, whose workers' states are pickled, or one without a seal),
naming this command. This command reads the checkpoint the same safe way, and then unpickles
the workers' states a v1 checkpoint holds (a one-worker Catch run's): the one place in the
project that unpickles a file, so that part runs whatever it holds; convert only a checkpoint
you trust (your own runs). It writes the same
network, optimizer statistics, step, flags and evaluations not taken yet, each worker's state in
the safe form (a3c_runtime.snapshots.saved_state), sealed; checks that the result loads safely;
and replaces the file atomically (the old one stays until the new one is whole), or writes
--out.
"""

from __future__ import annotations

import argparse
import io
import pickle
import sys
from pathlib import Path
from typing import Any

from a3c_tools import AGENTS, agent_scripts, load_script, run_main


def converted(checkpoint: dict) -> dict:
    """The safe form of a trusted, loaded checkpoint (any format this project wrote)."""
    from a3c_runtime.checkpoints import CHECKPOINT_FORMAT
    from a3c_runtime.snapshots import saved_state

    workers = {}
    for worker_id, states in (checkpoint.get("workers") or {}).items():
        if checkpoint.get("format") == CHECKPOINT_FORMAT:  # data already (an unsealed v2)
            workers[int(worker_id)] = states
            continue
        # the one place that unpickles: v1's worker states, on their owner's request
        parts = tuple(pickle.loads(state) if isinstance(state, bytes) else None for state in states)
        workers[int(worker_id)] = saved_state(parts)
    return {**checkpoint, "format": CHECKPOINT_FORMAT, "script": checkpoint.get("script", ""),
            "workers": workers,
            "pending_evaluations": list(checkpoint.get("pending_evaluations", []))}  # fmt: skip


def checked_by_its_script(checkpoint: Any) -> None:
    """The gate's checks of a checkpoint's flags by the script that wrote it, where that script
    is one of this clone's (a3c_runtime.checkpoints.for_agent); UsageError if they fail."""
    from a3c_runtime.checkpoints import for_agent

    if checkpoint.script in agent_scripts():
        for_agent(checkpoint, load_script(AGENTS / checkpoint.script).AGENT)


def convert(path: str, out: str) -> str:
    """Convert the checkpoint at path into out (which may be path); the line to print (one in
    the safe form already is left as it is). UsageError if it is corrupt or not a checkpoint."""
    import torch
    from a3c_runtime import UsageError
    from a3c_runtime.checkpoints import (
        NO_SEAL,
        UNSAFE_FORMATS,
        WriteFailed,
        check_checkpoint_path,
        checked,
        open_checkpoint,
        read_checkpoint,
        seal,
        verify_checkpoint,
        write_atomically,
    )

    check_checkpoint_path(path)
    data = Path(path).read_bytes()
    problem = verify_checkpoint(data)
    if problem not in (None, NO_SEAL):
        raise UsageError(f"checkpoint {path!r} is corrupt: {problem}")
    if problem is None:
        try:
            read_checkpoint(path)
        except UsageError:
            pass  # an older format, or unsafe: converted below
        else:
            checked_by_its_script(open_checkpoint(path))  # a malformed one is refused all the same
            return f"{path} is in the safe form already: nothing to do"
    try:  # the checkpoint itself is data in every format; only v1's worker states are pickles
        checkpoint = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        lines = str(e).strip().splitlines()
        detail = next((line.strip() for line in lines if "Unsupported" in line), lines[0])
        raise UsageError(
            f"checkpoint {path!r} holds more than any checkpoint of the agent scripts ({detail}): "
            f"not converted"
        ) from None
    except Exception as e:
        detail = (str(e).strip().splitlines() or [type(e).__name__])[0]
        raise UsageError(f"checkpoint {path!r} is corrupt or not a torch file: {detail}") from e
    if not isinstance(checkpoint, dict) or not isinstance(checkpoint.get("global_step"), int):
        raise UsageError(f"{path!r} is not a checkpoint written by the agent scripts")
    old_format = checkpoint.get("format")
    try:
        safe = converted(checkpoint)
    except (AttributeError, TypeError, ValueError) as e:
        raise UsageError(f"checkpoint {path!r} is malformed: {e}") from None
    buffer = io.BytesIO()
    torch.save(safe, buffer)
    sealed = seal(buffer.getvalue())
    try:  # what is written must load safely, and pass the gate
        safe = torch.load(io.BytesIO(sealed), map_location="cpu", weights_only=True)
        checked_by_its_script(checked(safe, path))
    except pickle.UnpicklingError as e:
        detail = (str(e).strip().splitlines() or [""])[0]
        raise UsageError(f"checkpoint {path!r} holds what has no safe form: {detail}") from None
    try:
        write_atomically(Path(out), sealed)
    except WriteFailed as e:
        raise UsageError(str(e)) from None
    was = old_format if old_format in UNSAFE_FORMATS else f"{old_format}, unsealed"
    return (
        f"converted {path} ({was}, step {int(checkpoint['global_step']):,}) -> {out}: it "
        f"loads safely now"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", help="a checkpoint.pt you trust, from before safe loading")
    parser.add_argument("-o", "--out", help="write the safe form here (default: in place)")
    args = parser.parse_args(argv)
    from a3c_runtime import UsageError

    try:
        print(convert(args.checkpoint, args.out or args.checkpoint))
    except UsageError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    run_main(main)
