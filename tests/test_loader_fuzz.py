"""Files from someone else, fuzzed (issue 103, point 3): every loader of a file the tools read
(a sweep's sweep.json, a campaign's or a study's plan TOML, a sweep's results.csv), given
10,000 seeded mutations of a committed file each (byte flips, truncations, repeated spans,
huge numbers, nesting past any parser's depth, fields of another type), loads it or refuses it
with its one-line error, each within 1 s and 200 MB. Checkpoints have their own fuzz test
(test_checkpoint_format.py)."""

import json
import random
import resource
import time
from collections.abc import Callable
from pathlib import Path

import pytest
from a3c_tools import campaign, compare, sweep
from a3c_tools.figure_sweeps import DataError
from conftest import ROOT

FILES = 10_000
SEEDS = {  # a committed file of each kind, the fuzz's starting point
    "sweep.json": ROOT / "results" / "confirmatory" / "catch" / "ff_as_run" / "sweep.json",
    "plan.toml": ROOT / "results" / "confirmatory_1m" / "plan.toml",
    "results.csv": ROOT / "results" / "confirmatory" / "catch" / "ff_as_run" / "results.csv",
}
JUNK = [b"[" * 100_000, b"{" * 100_000, b"9" * 5000, b"1e999999", b"-0", b"\x00", b"\xff\xfe",
        b'"', b"\n", b",", b"NaN", b"inf", b"[[item]]\n", b'x = "', b"= =",
        b"\r\n" * 3]  # fmt: skip


def mutated(data: bytes, rng: random.Random) -> bytes:
    """One random change, or a few, of the file's bytes."""
    for _ in range(rng.choice((1, 1, 2, 3))):
        if not data:
            data = rng.choice(JUNK)
            continue
        at = rng.randrange(len(data))
        kind = rng.randrange(6)
        if kind == 0:  # flip a byte
            data = data[:at] + bytes([rng.randrange(256)]) + data[at + 1 :]
        elif kind == 1:  # cut the file short
            data = data[:at]
        elif kind == 2:  # junk in
            data = data[:at] + rng.choice(JUNK) + data[at:]
        elif kind == 3:  # a span repeated
            span = data[at : at + rng.randrange(1, 200)]
            data = data[:at] + span * rng.randrange(2, 50) + data[at:]
        elif kind == 4:  # a span dropped
            data = data[:at] + data[at + rng.randrange(1, 200) :]
        else:  # a number made huge or odd
            data = data[:at] + rng.choice((b"99999999999999999999999", b"-1", b"1e308", b"0.5"))
            data += data[at:]
    return data


def structural(config: dict, rng: random.Random) -> bytes:
    """A sweep.json whose fields keep their JSON shape but take values of another type."""
    config = dict(config)
    name = rng.choice(list(config))
    config[name] = rng.choice([None, 1, -5, 1e300, "x", [], {}, [[[]]], {"a": [1]}, True, "" * 10])
    if rng.random() < 0.2:
        del config[rng.choice(list(config))]
    return json.dumps(config).encode()


def fuzz(
    tmp_path: Path, name: str, load: Callable[[Path], object], refusals: tuple, seed: int
) -> tuple[int, int]:
    """Feed `load` FILES mutations of SEEDS[name]: each loads, or raises one of `refusals` with a
    one-line message, within 1 s and 200 MB. Returns (loaded, refused)."""
    original = SEEDS[name].read_bytes()
    config = json.loads(original) if name == "sweep.json" else None
    rng, loaded, refused = random.Random(seed), 0, 0
    path = tmp_path / name
    for i in range(FILES):
        data = structural(config, rng) if config and rng.random() < 0.3 else mutated(original, rng)
        path.write_bytes(data)
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
        start = time.perf_counter()
        try:
            load(path)
            loaded += 1
        except refusals as e:
            assert "\n" not in str(e).strip(), (name, i, str(e))
            refused += 1
        assert time.perf_counter() - start < 1.0, (name, i)
        grown = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - before) / 1024
        assert grown < 200, (name, i, f"{grown:.0f} MB")
    return loaded, refused


@pytest.mark.slow
def test_fuzzed_sweep_configurations_load_or_are_refused_in_one_line(tmp_path):
    loaded, refused = fuzz(tmp_path, "sweep.json",
                           lambda p: sweep.read_config(p, ("script", "fixed_flags", "seed")),
                           (sweep.UsageError,), seed=1031)  # fmt: skip
    assert loaded > 100 and refused > 1000


@pytest.mark.slow
def test_fuzzed_plans_load_or_are_refused_in_one_line(tmp_path):
    loaded, refused = fuzz(tmp_path, "plan.toml", campaign.load_plan, (DataError,), seed=1032)
    assert loaded > 100 and refused > 1000


@pytest.mark.slow
def test_fuzzed_results_tables_load_or_are_refused_in_one_line(tmp_path):
    loaded, refused = fuzz(tmp_path, "results.csv", lambda p: compare.check_table(p, "score"),
                           (compare.UsageError,), seed=1033)  # fmt: skip
    assert loaded > 100 and refused > 100
