"""Issue 103: a checkpoint is data by construction. The attacks a pickled container could carry
(a list nested 80 deep holding the same list twice at each level, in `workers` or in a flag;
200,000 pending evaluations of one network; a stride-0 view of 40 GB; a self-referencing list;
a sparse or complex tensor) end in one line and exit 2 within seconds and bounded memory at
every reader: the scripts refuse the older format outright, the converter (its one reader)
refuses what the current format cannot hold. And a fuzz test of the gate (slow tier)."""

import dataclasses
import hashlib
import io
import json
import random
import resource
import subprocess
import sys
import time

import a3c_runtime as runtime
import pytest
import torch
from a3c_tools import convert_checkpoint
from conftest import FORK, ROOT, load_script, main_exit, read_checkpoint, shared_for, tiny_args


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """A real a3c_ff.py checkpoint with a pending evaluation."""
    module = load_script("a3c_ff")
    args = tiny_args(module)
    shared = shared_for(module, args)
    path = tmp_path_factory.mktemp("good") / "checkpoint.pt"
    pending = [(1000, runtime.snapshots.copy_of(shared.model.state_dict()))]
    runtime.save_checkpoint(path, shared, args, 1.0, "a3c_ff.py", {"pending_evaluations": pending})
    return path


def doubled(depth: int) -> list:
    """A list `depth` deep whose every level holds the next one twice: 2**depth paths."""
    value: list = []
    for _ in range(depth):
        value = [value, value]
    return value


def self_referencing() -> list:
    value: list = []
    value.append(value)
    return value


ATTACKS = {  # a part of an older-format checkpoint, changed
    "80 deep, doubled, in workers": lambda c: c.update(workers={0: [doubled(80)] * 3}),
    "80 deep, doubled, in a flag": lambda c: c["args"].update(exp_name=doubled(80)),
    "200,000 pending evaluations of one network": lambda c: c.update(
        pending_evaluations=[(1000, c["model"])] * 200_000
    ),
    "a stride-0 view of 10**10 floats": lambda c: c["model"].update(
        {"value.weight": torch.zeros(1).expand(100_000, 100_000)}
    ),
    "a self-referencing list in workers": lambda c: c.update(workers={0: self_referencing()}),
    "a self-referencing list in a flag": lambda c: c["args"].update(exp_name=self_referencing()),
    "a sparse tensor": lambda c: c["model"].update(
        {"value.weight": c["model"]["value.weight"].to_sparse()}
    ),
    "a complex tensor": lambda c: c["model"].update(
        {"value.weight": c["model"]["value.weight"] * (1 + 1j)}
    ),
}


def older_format(good, path, attack: str) -> None:
    """The good checkpoint in the older format (a sealed torch zip), with the attack in it."""
    old = {k: v for k, v in read_checkpoint(good).items() if k != "pending_steps"}
    old.update(format="a3c-checkpoint-v2", network="ActorCritic")
    ATTACKS[attack](old)
    buffer = io.BytesIO()
    torch.save(old, buffer)
    # (the seal of the older format: the converter's now, the runtime's before)
    seal = getattr(convert_checkpoint, "seal", None) or runtime.checkpoints.seal
    path.write_bytes(seal(buffer.getvalue()))


# run in a child with its address space bounded (4 GiB) and each reader given 10 s: a reader
# that walks, allocates or recurses ends in a traceback there, not in a hung or swapping test
READERS = r"""
import contextlib, io, json, resource, signal, sys, time
resource.setrlimit(resource.RLIMIT_AS, (4 << 30, 4 << 30))
sys.path.insert(0, "tests")
from conftest import load_script
from a3c_tools import convert_checkpoint, record_play

def timed_out(*_):
    raise TimeoutError("over 10 s")

signal.signal(signal.SIGALRM, timed_out)
ff = load_script("a3c_ff")
results = {}

def script(mode, path):
    sys.argv = ["a3c_ff.py", mode, path]
    return ff.main()

for path in sys.argv[1:]:
    for reader, call in (
        ("--evaluate", lambda: script("--evaluate", path)),
        ("--resume", lambda: script("--resume", path)),
        ("record_play", lambda: record_play.main([path, "-o", path + ".gif"])),
        ("convert_checkpoint", lambda: convert_checkpoint.main([path, "-o", path + ".new"])),
    ):
        err, start = io.StringIO(), time.time()
        signal.alarm(10)
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                code = call()
        except BaseException as e:
            code = f"{type(e).__name__}: {str(e)[:200]}"
        signal.alarm(0)
        results[f"{path} {reader}"] = [code, err.getvalue(), time.time() - start]
print(json.dumps(results))
"""


def test_an_older_checkpoint_holding_an_attack_is_one_line_at_every_reader(good, tmp_path):
    paths = {}
    for i, attack in enumerate(ATTACKS):
        paths[attack] = tmp_path / f"run{i}" / "checkpoint.pt"
        paths[attack].parent.mkdir()
        older_format(good, paths[attack], attack)
    assert paths["200,000 pending evaluations of one network"].stat().st_size < 16 << 20
    result = subprocess.run(
        [sys.executable, "-c", READERS, *map(str, paths.values())],
        capture_output=True, text=True, cwd=ROOT, timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, result.stderr[-2000:]
    results = json.loads(result.stdout.splitlines()[-1])
    for attack, path in paths.items():
        for reader in ("--evaluate", "--resume", "record_play", "convert_checkpoint"):
            code, err, seconds = results[f"{path} {reader}"]
            assert code == 2 and err.count("\n") == 1, (attack, reader, code, err)
            assert seconds < 5, (attack, reader, seconds)
            if reader == "convert_checkpoint":  # the converter read it, and refused it
                assert "older format" not in err, (attack, err)
            else:
                assert "is of the older format (a torch zip), which is not loaded" in err
        assert not list(path.parent.glob("*.new")) and not list(path.parent.glob("*.gif"))


@pytest.mark.parametrize("where", ["swapped", "beyond the file", "bytes left over"])
def test_tensors_not_where_the_header_puts_them_are_one_line(
    where, good, tmp_path, monkeypatch, capsys
):
    """Where each tensor's bytes lie (in order, each of its shape's size, filling the file) is
    safetensors' loader's check: a sealed file whose tensor table is the network's but whose
    bytes are not where the table puts them is refused in one line, exit 2, nothing allocated
    by the offsets it declares."""
    data = good.read_bytes()
    size = int.from_bytes(data[:8], "little")
    header, tensors = json.loads(data[8 : 8 + size]), data[8 + size :]
    a, b = header["model/value.weight"], header["model/policy.weight"]  # of 256 and 768 floats
    if where == "swapped":
        a["data_offsets"], b["data_offsets"] = b["data_offsets"], a["data_offsets"]
    elif where == "beyond the file":
        a["data_offsets"] = [a["data_offsets"][0], 2**62]
    else:
        tensors += bytes(64)
    path = tmp_path / "run" / "checkpoint.pt"
    path.parent.mkdir()
    path.write_bytes(resealed(header, tensors))
    before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    code, err = main_exit(load_script("a3c_ff"), ["--evaluate", str(path)], monkeypatch, capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert f"checkpoint {str(path)!r} is corrupt: " in err, err
    assert (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024 < 200  # MB


# ------------------------------------------------------------------------------------------------
# The fuzz test: files made from a good checkpoint by byte flips, truncations, huge declared
# sizes and changes of its structure (fields, tensors, the header), each loaded by the gate in
# process: refused in one line (UsageError) or loaded, within 1 s and 200 MB; a sample through
# the command line. (JSON holds no shared or cyclic references: nothing of the kind to try.)
# The good checkpoint is a3c_ff.py's with every part, of a network with FF's layers at a few
# hundred parameters: the gate reads any size by the same code (the huge sizes are mutants of
# their own), and at the thesis network's 16.5 MB a file took 24 ms to copy, reseal and hash
# where its header, the gate's most intricate reading, is 0.03% of its bytes.
# ------------------------------------------------------------------------------------------------
JUNK = [None, True, -1, 0, 2**64, 10**30, 1.5, float("nan"), "", "x" * 5000, [], {}, [1], {"a": 1}]


def mutated(data: bytes, rng: random.Random) -> bytes:
    """One mutant of the checkpoint file `data`."""
    kind = rng.randrange(6)
    size = int.from_bytes(data[:8], "little")
    if kind == 0:  # byte flips, anywhere
        out = bytearray(data)
        for _ in range(rng.randint(1, 8)):
            out[rng.randrange(len(out))] ^= 1 << rng.randrange(8)
        return bytes(out)
    if kind == 1:  # byte flips in the header
        out = bytearray(data)
        for _ in range(rng.randint(1, 4)):
            out[rng.randrange(8 + size)] = rng.randrange(256)
        return bytes(out)
    if kind == 2:  # a truncation
        return data[: rng.randrange(len(data))]
    if kind == 3:  # a huge declared header
        return rng.choice([2**63, 2**40, size + 1, len(data)]).to_bytes(8, "little") + data[8:]
    header = json.loads(data[8 : 8 + size])
    document = json.loads(header["__metadata__"]["a3c"])
    if kind == 4:  # a field of the document, a flag or a worker's Catch games, junk in its place
        games = document["workers"]["0"]
        key = rng.choice([*document["args"], *document, *(f"games/{k}" for k in games)])
        if key.startswith("games/") and rng.random() < 0.5:  # one game's value
            values = games[key[len("games/") :]]
            values[rng.randrange(len(values))] = rng.choice(JUNK)
        elif key.startswith("games/"):  # every game's
            games[key[len("games/") :]] = rng.choice(JUNK)
        else:
            target = document["args"] if key in document["args"] else document
            target[key] = rng.choice(JUNK)
        header["__metadata__"]["a3c"] = json.dumps(document)
    else:  # a tensor's declared dtype, shape or name changed (a huge shape among them)
        name = rng.choice([n for n in header if n != "__metadata__"])
        choice = rng.randrange(4)
        if choice == 0:
            header[name]["shape"] = [rng.choice([2**40, 2**31, 10**6, 0, 3]), 1 << 20]
        elif choice == 1:
            header[name]["dtype"] = rng.choice(["F64", "I64", "U8", "C64", "F8_E4M3"])
        elif choice == 2:
            header[name + "x"] = header.pop(name)
        else:
            header[name]["data_offsets"] = [0, 2**62]
    return resealed(header, data[8 + size :])


def resealed(header: dict, tensors: bytes) -> bytes:
    """A file of this header and these tensor bytes, sealed as checkpoint_file seals it."""
    from a3c_runtime.checkpoint_file import SEAL, seal_field

    header["__metadata__"]["sha256"] = SEAL
    text = json.dumps(header, separators=(",", ":")).encode()
    data = len(text).to_bytes(8, "little") + text + tensors
    digest = hashlib.sha256(data).hexdigest()
    return data.replace(seal_field(SEAL), seal_field(digest), 1)


def small_network(num_actions: int, args) -> torch.nn.Module:
    """FF's layers (their names: torso, policy, value), 2 channels and 4 units wide."""
    network = torch.nn.Module()
    network.torso = torch.nn.Sequential(
        torch.nn.Conv2d(4, 2, 8, stride=4), torch.nn.ReLU(), torch.nn.Conv2d(2, 2, 4, stride=2),
        torch.nn.ReLU(), torch.nn.Flatten(), torch.nn.Linear(2 * 9 * 9, 4), torch.nn.ReLU(),
    )  # fmt: skip
    network.policy, network.value = torch.nn.Linear(4, num_actions), torch.nn.Linear(4, 1)
    return network


@pytest.mark.slow
def test_fuzzed_checkpoints_load_or_are_refused_in_one_line(tmp_path, monkeypatch, capsys):
    from test_safe_loading import catch_worker_state

    module = load_script("a3c_ff")
    agent = dataclasses.replace(module.AGENT, network=small_network)
    args = tiny_args(module, envs_per_worker=2)  # (catch_worker_state's envs)
    shared = runtime.Shared(agent.build_network(3, args), args, FORK)
    path = tmp_path / "checkpoint.pt"
    snapshot = {  # every part a checkpoint can have: a worker's Catch games, an evaluation
        "workers": {0: runtime.snapshots.saved_state(catch_worker_state())},
        "pending_evaluations": [(1000, runtime.snapshots.copy_of(shared.model.state_dict()))],
    }
    runtime.save_checkpoint(path, shared, args, 1.0, "a3c_ff.py", snapshot)
    data = path.read_bytes()
    rng = random.Random(103)
    refused, loaded, sample = 0, 0, []
    for i in range(10_000):
        blob = mutated(data, rng)
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        start = time.perf_counter()
        try:
            checkpoint = runtime.checkpoints.open_checkpoint("fuzz.pt", data=blob)
            runtime.checkpoints.for_agent(checkpoint, agent)
            loaded += 1
        except runtime.UsageError as e:
            assert "\n" not in str(e), (i, str(e))
            refused += 1
            if len(sample) < 20 and rng.random() < 0.01:
                sample.append(blob)
        assert time.perf_counter() - start < 1.0, i
        grown = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
        assert grown < 200, (i, f"{grown:.0f} MB")  # (the peak, in MB)
    assert refused > 5000 and loaded > 0, (refused, loaded)
    # a sample through the command line: one line, exit 2
    for j, blob in enumerate(sample):
        path = tmp_path / f"sample{j}.pt"
        path.write_bytes(blob)
        code, err = main_exit(module, ["--evaluate", str(path)], monkeypatch, capsys)
        assert code == 2 and err.count("\n") == 1, err
