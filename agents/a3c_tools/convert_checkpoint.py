"""A checkpoint of an older format (a torch zip: v1 or v2, sealed or not; or v3, safetensors with
its Catch arrays and generators in the older layout) converted into the current one (v4,
safetensors with a declared document, a3c_runtime.checkpoint_file), on its owner's explicit
request:

    python -m a3c_tools.convert_checkpoint runs/<run>/checkpoint.pt

The agent scripts and the tools read only the current format; they refuse an older one, naming
this command. This command checks the zip (every member's CRC, the sizes its members declare,
its seal if it has one), loads it with `torch.load(weights_only=True)`, which builds tensors,
numbers, strings, lists, tuples and dicts and runs no code, and reads each field it knows by
name (no walk through what a field holds), refusing anything the current format cannot hold.
A v1 checkpoint's worker states are pickled: they are unpickled, the one place in the project
that unpickles a file, so convert only a checkpoint you trust (your own runs). What it writes
passes the gate of the script that wrote it before it replaces the file atomically (the old one
stays until the new one is whole), or is written to --out. A thesis script's checkpoint
with one of chapter 8's flags set (from before each became a script of its own) is converted
as the future-work script's, which plays and resumes it.
"""

from __future__ import annotations

import argparse
import hashlib
import io
import pickle
import struct
import sys
import zipfile
from pathlib import Path
from typing import Any

from a3c_tools import AGENTS, agent_scripts, load_script, run_main

OLD_FORMATS = ("a3c-checkpoint-v1", "a3c-checkpoint-v2")  # v1: its worker states pickled
# what a checkpoint that does not hold what its format should raises while it is converted
MALFORMED = (KeyError, TypeError, ValueError, AttributeError, IndexError, OverflowError,
             RecursionError, RuntimeError, pickle.UnpicklingError)  # fmt: skip
# Chapter 8's ideas were flags of the thesis scripts before each became a script of its own in
# agents/future_work/: a checkpoint an older thesis script wrote with one of them set belongs to
# that script
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
# the older format's seal: the zip's comment holds the SHA-256 of every byte before it
SEAL_PREFIX = b"a3c-sha256:"
END_OF_ARCHIVE = b"PK\x05\x06"  # the end-of-central-directory record: 22 bytes + the comment


def seal(archive: bytes) -> bytes:
    """A zip torch.save wrote, with the SHA-256 of its bytes as its comment (the older format's
    seal; tests write such checkpoints with it)."""
    if archive[-22:-18] != END_OF_ARCHIVE or archive[-2:] != b"\x00\x00":
        raise ValueError("the archive does not end in a comment-less end-of-central-directory")
    length = len(SEAL_PREFIX) + hashlib.sha256().digest_size * 2
    head = archive[:-2] + struct.pack("<H", length)  # the comment's length is sealed too
    return head + SEAL_PREFIX + hashlib.sha256(head).hexdigest().encode()


def zip_problem(data: bytes) -> str | None:
    """What is wrong with the older format's bytes, or None: not a whole zip, members declaring
    more bytes than the file (torch stores them uncompressed), a CRC that fails, no data.pkl, a
    seal that does not match."""
    try:
        with zipfile.ZipFile(io.BytesIO(data)) as archive:
            declared = sum(member.file_size for member in archive.infolist())
            if declared > len(data):
                return f"its members declare {declared:,} bytes, more than the {len(data):,} it has"
            bad_member = archive.testzip()  # reads every member, checking its CRC
            comment, names = archive.comment, archive.namelist()
    except (zipfile.BadZipFile, zipfile.LargeZipFile, EOFError, ValueError) as e:
        return f"not a whole zip archive ({e})"
    if bad_member is not None:
        return f"{bad_member} fails its CRC check"
    if not any(name.endswith("/data.pkl") for name in names):
        return "not a torch file (a zip archive without data.pkl)"
    head = data[: len(data) - len(comment)]
    if comment and comment != SEAL_PREFIX + hashlib.sha256(head).hexdigest().encode():
        return "its bytes do not match the SHA-256 it was written with"
    return None


def converted(old: Any) -> dict:
    """The fields of an older checkpoint (torch.load's dict), each read by name and of the form
    save_checkpoint hands on; ValueError naming what is not."""
    from a3c_runtime.checkpoint_file import MAX_PENDING
    from a3c_runtime.checkpoints import MAX_WORKERS
    from a3c_runtime.snapshots import saved_state

    if not isinstance(old, dict) or old.get("format") not in OLD_FORMATS:
        raise ValueError("it is not a checkpoint written by the agent scripts")
    pending, workers = old.get("pending_evaluations", []), old.get("workers") or {}
    if not isinstance(pending, (list, tuple)) or len(pending) > MAX_PENDING:
        raise ValueError(f"its pending evaluations are not a list of at most {MAX_PENDING:,}")
    if not isinstance(workers, dict) or len(workers) > MAX_WORKERS:
        raise ValueError(f"its workers are not a dict of at most {MAX_WORKERS:,}")
    states = {}
    for worker_id, state in workers.items():
        if not isinstance(state, (list, tuple)) or len(state) not in (3, 4):
            raise ValueError(f"worker {worker_id!r}'s state is not a worker's")
        if old["format"] == "a3c-checkpoint-v1":  # on its owner's request (the module docstring)
            state = saved_state(tuple(pickle.loads(s) if isinstance(s, bytes) else None
                                      for s in state))  # fmt: skip
        states[worker_id] = list(state)
    for request in pending:
        if not isinstance(request, (list, tuple)) or len(request) != 2:
            raise ValueError("a pending evaluation is not a (step, network) pair")
    return {
        **{
            key: old[key] for key in ("model", "optimizer", "global_step", "wall_time", "args")
        },  # fmt: skip
        "script": old.get("script", ""),
        "workers": states,
        "pending_evaluations": [tuple(request) for request in pending],
    }


def v3_fields(data: bytes) -> dict | None:
    """The fields of a v3 checkpoint (safetensors; its Catch arrays, canvas included, and its
    generators' words in the document), of the form save_checkpoint hands on; None if data is
    not one."""
    import json

    import safetensors.torch
    from a3c_runtime.checkpoint_file import SEAL, runtime_form, seal_field

    try:
        header = json.loads(data[8 : 8 + int.from_bytes(data[:8], "little")])
        document, seal = json.loads(header["__metadata__"]["a3c"]), header["__metadata__"]["sha256"]
        if document["format"] != "a3c-checkpoint-v3":
            return None
    except (ValueError, KeyError, TypeError, RecursionError):
        return None
    if seal != hashlib.sha256(data.replace(seal_field(seal), seal_field(SEAL), 1)).hexdigest():
        raise ValueError("its bytes do not match the SHA-256 it was written with")  # (v4's seal)
    tensors = safetensors.torch.load(data)
    workers = {}
    for worker_id, worker in document["workers"].items():
        prefix = f"workers/{worker_id}/"
        own = {n.removeprefix(prefix): t for n, t in tensors.items() if n.startswith(prefix)}
        env = None
        if worker["env"] is not None:  # the wrapper's arrays at env/, the games' at env/env/
            inner = {n[len("env/env/") :]: t for n, t in own.items() if n.startswith("env/env/")}
            inner["rngs"] = [v3_generator(s) for s in worker["env"]]
            env = {"env": {**{k: own[f"env/{k}"] for k in ("stack", "returns", "lengths")},
                           "env": inner}}  # fmt: skip
        carried = tuple(own[f"lstm/{j}"] for j in range(sum(n.startswith("lstm/") for n in own)))
        workers[int(worker_id)] = [{"bit_generator": v3_generator(worker["generator"])}, env,
                                   own["frames"], *([carried] if carried else [])]  # fmt: skip
    fields = runtime_form(tensors, {**document, "workers": {}})  # its model and optimizer
    kept = {k: document[k] for k in ("script", "global_step", "wall_time", "args", "format")}
    return {**kept, **fields, "workers": workers}


def v3_generator(state: dict) -> dict:
    """A PCG64 state as v3 held it (its 128-bit words in decimal) as NumPy's."""
    return {**state, "state": {k: int(v) for k, v in state["state"].items()}}


def attributed(fields: dict) -> dict:
    """fields with the script that plays and resumes them (MOVED_FLAGS)."""
    for (flag, value), owner in MOVED_FLAGS.get(fields["script"], {}).items():
        if fields["args"].get(flag) == value:
            return {**fields, "script": owner}
    return fields


def checked_by_its_script(checkpoint: Any) -> None:
    """The gate's checks of a checkpoint by the script that wrote it, where that script is one
    of this clone's (a3c_runtime.checkpoints.for_agent); UsageError if they fail."""
    from a3c_runtime.checkpoints import for_agent

    if checkpoint.script in agent_scripts():
        for_agent(checkpoint, load_script(AGENTS / checkpoint.script).AGENT)


def convert(path: str, out: str) -> str:
    """Convert the checkpoint at path into out (which may be path); the line to print (one in
    the current format already is left as it is). UsageError if it is corrupt, not a checkpoint,
    or holds what the current format cannot."""
    import torch
    from a3c_runtime import UsageError
    from a3c_runtime.checkpoints import (
        check_checkpoint_path,
        open_checkpoint,
        problem_of,
    )

    check_checkpoint_path(path)
    data = Path(path).read_bytes()
    if data[:2] != b"PK":  # not a zip: v3, the current format, or nothing of ours
        import safetensors

        try:
            old = v3_fields(data)
        except (*MALFORMED, safetensors.SafetensorError) as e:
            raise UsageError(f"checkpoint {path!r} is corrupt: {problem_of(e)}") from None
        if old is None:
            checked_by_its_script(open_checkpoint(path, data=data))
            return f"{path} is in the current format already: nothing to do"
        return written(path, out, old)
    problem = zip_problem(data)
    if problem is not None:
        raise UsageError(f"checkpoint {path!r} is corrupt: {problem}")
    try:  # the checkpoint itself is data in every format; only v1's worker states are pickles
        old = torch.load(io.BytesIO(data), map_location="cpu", weights_only=True)
    except pickle.UnpicklingError as e:
        lines = str(e).strip().splitlines()
        detail = next((line.strip() for line in lines if "Unsupported" in line), lines[0])
        raise UsageError(
            f"checkpoint {path!r} holds more than any checkpoint of the agent scripts ({detail}): "
            f"not converted"
        ) from None
    except Exception as e:
        raise UsageError(
            f"checkpoint {path!r} is corrupt or not a torch file: {problem_of(e)}"
        ) from None
    try:
        fields = {**converted(old), "format": old["format"]}
    except MALFORMED as e:
        raise UsageError(f"checkpoint {path!r} is malformed: {problem_of(e)}") from None
    return written(path, out, fields)


def written(path: str, out: str, old: dict) -> str:
    """The older checkpoint's fields (`old`, its `format` among them) written to out in the
    current format, once what is written passes the gate of its script; the line to print."""
    from a3c_runtime import UsageError
    from a3c_runtime.checkpoints import (
        WriteFailed,
        encode,
        open_checkpoint,
        problem_of,
        write_atomically,
    )

    try:
        new = encode(attributed({k: v for k, v in old.items() if k != "format"}))
    except MALFORMED as e:
        raise UsageError(f"checkpoint {path!r} is malformed: {problem_of(e)}") from None
    checked_by_its_script(open_checkpoint(path, data=new))  # what is written passes the gate
    try:
        write_atomically(Path(out), new)
    except WriteFailed as e:
        raise UsageError(str(e)) from None
    return f"converted {path} ({old['format']}, step {old['global_step']:,}) -> {out}"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", help="a checkpoint.pt of the older format that you trust")
    parser.add_argument("-o", "--out", help="write the current format here (default: in place)")
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
