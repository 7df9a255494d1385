"""Faults injected into real runs: is a run ever lost?

    python benchmarks/fault_injection.py [--trials 20] [--total-timesteps 60000] [--seed 0]

Each trial starts a short A3C FF run on Catch-v0 (agents/a3c_ff.py, 2 workers, the fast setting
--envs-per-worker 16, checkpoints every 5,000 steps, a learning rate and seed of the trial's
own) and hits it at a random time (1-12 s after its processes start) with a fault, the trials
taking the faults in turn:

- SIGKILL of a worker, SIGKILL of the main process, SIGTERM or SIGINT of the main process;
- the disk filling up: the run folder lies on a small tmpfs (mounted here; needs root), which a
  file fills at the random time, so that the run's next write fails. The file is removed before
  the run is resumed, as a user would free the space;
- a corrupt checkpoint: once the run has ended, 64 bytes in the middle of its checkpoint are
  flipped; `--resume` must refuse it in one line, exit code 2, leaving the file as it is; then
  the good bytes are put back, as from a backup;
- a sweep race: two sweeps of tiny runs started at the same instant into one new --out; exactly
  one must run (its run recorded once), the other exit 2 naming the folder's holder.

Then it resumes the run (`--resume <run>/checkpoint.pt`, nothing else) until it reaches its
target step, or starts it again where the fault came before its first checkpoint. It checks:
that every checkpoint there was before a fault is still there and loads (a checkpoint "lost"
otherwise), that no partial file (*.tmp) is left, that every process of every attempt is gone
once it ends (an "orphan" otherwise), that the faulted run exited as it should (0 after SIGTERM
or SIGINT, 1 after a worker's death or a failed write, the signal after SIGKILL) with its last
line naming the surviving checkpoint and how to resume (or, with none yet, how to start again),
that the run reached its target step, and that the finished run's flags are the ones it was
started with. It prints a line per trial and the totals; the exit code is 1 if any check failed.
"""

from __future__ import annotations

import argparse
import os
import random
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from a3c_runtime.checkpoints import read_checkpoint
from a3c_runtime.flags import UsageError

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "agents" / "a3c_ff.py"
FAULTS = ("SIGKILL worker", "SIGKILL main", "SIGTERM", "SIGINT", "disk full", "corrupt checkpoint",
          "sweep race")  # fmt: skip
# the closing line of a run that ended before its last step (a3c_runtime.a3c.resume_hint): the
# checkpoint that survives and how to resume it, or, with none that reads, how to start again
HINT = (
    r"(checkpoint \S+ \(step [\d,]+\) survives; resume: python \S+ --resume "
    r"|(no checkpoint was written in \S+|checkpoint \S+ does not verify \(corrupt\)); "
    r"start the run again: (rm -r -- \S+ && )?python )"
)
DISK_BYTES = 64 << 20  # the tmpfs of a disk-full trial: room for the run, until it is filled


def checkpoint_state(path: Path) -> dict | None:
    """The checkpoint's step and flags if it reads safely (its seal verified, its document
    valid: a3c_runtime.checkpoint_file), else None."""
    try:
        checkpoint = read_checkpoint(str(path))[0]
        return {"step": int(checkpoint["global_step"]), "args": checkpoint["args"]}
    except (UsageError, KeyError, TypeError, ValueError):
        return None


def alive(pid: int) -> bool:
    """Whether pid runs (a zombie, exited but not yet reaped by its parent, does not)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(") ", 1)[1][0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


def orphans(pids: dict[str, int], timeout: float = 15.0) -> list[str]:
    deadline = time.time() + timeout
    while time.time() < deadline and any(alive(pid) for pid in pids.values()):
        time.sleep(0.1)
    left = [f"{name} {pid}" for name, pid in pids.items() if alive(pid)]
    for name in left:  # clean up for the next trial
        os.kill(int(name.rsplit(" ", 1)[1]), 9)
    return left


class Attempt:
    """One start of the script, its output read in the background."""

    def __init__(self, args: list[str]):
        self.log = tempfile.TemporaryFile(mode="w+")  # noqa: SIM115 (read while it runs)
        self.process = subprocess.Popen(
            [sys.executable, str(SCRIPT), *args], stdout=self.log, stderr=subprocess.STDOUT,
            text=True, cwd=ROOT, start_new_session=True,
        )  # fmt: skip
        self.pids: dict[str, int] = {}

    def output(self) -> str:
        self.log.seek(0)
        return self.log.read()

    def wait_for_pids(self, timeout: float = 60.0) -> bool:
        deadline = time.time() + timeout
        while time.time() < deadline:
            match = re.search(r"^pids: (.*)$", self.output(), re.M)
            if match:
                self.pids = {m[0]: int(m[1]) for m in re.findall(r"(\w+ ?\d*) (\d+)", match[1])}
                return True
            if self.process.poll() is not None:
                return False
            time.sleep(0.05)
        return False


def mount_tmpfs(path: Path) -> bool:
    path.mkdir(parents=True, exist_ok=True)
    command = ["mount", "-t", "tmpfs", "-o", f"size={DISK_BYTES}", "tmpfs", str(path)]
    return subprocess.run(command, capture_output=True).returncode == 0


def fill(disk: Path) -> Path:
    """A file that takes all the free space of disk."""
    filler = disk / "filler"
    with open(filler, "wb") as f:
        chunk = b"\0" * (1 << 20)
        try:
            while True:
                f.write(chunk)
                f.flush()
        except OSError:
            pass
    return filler


def sweep_race(index: int, work: Path) -> dict:
    """Two sweeps of one tiny run each, started at the same instant into one new --out."""
    out = work / f"race{index}"
    command = [sys.executable, "-m", "a3c_tools.sweep", str(SCRIPT), "--out", str(out), "--runs",
               "1", "--total-timesteps", "1000", "--", "--num-workers", "1", "--eval-interval",
               "500", "--eval-episodes", "2"]  # fmt: skip
    sweeps = [subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                               text=True, cwd=ROOT) for _ in range(2)]  # fmt: skip
    done = [sweep.communicate(timeout=300) for sweep in sweeps]
    codes = sorted(sweep.returncode for sweep in sweeps)
    loser = next((err for sweep, (_, err) in zip(sweeps, done, strict=True)
                  if sweep.returncode == 2), "")  # fmt: skip
    rows = (
        (out / "results.csv").read_text().splitlines()[1:] if (out / "results.csv").exists() else []
    )
    ok = codes == [0, 2] and "held by another sweep" in loser and len(rows) == 1
    return {"fault": "sweep race", "lost": 0, "orphans": [], "attempts": 2, "restarted": False,
            "exit": codes[-1], "ended_as_promised": ok, "partial_files": 0, "reached": ok,
            "same_flags": ok, "final_step": 1000 if ok else None,
            "last_line": (loser.strip().splitlines() or [""])[-1][:160]}  # fmt: skip


def trial(index: int, fault: str, rng: random.Random, total: int, work: Path) -> dict:
    if fault == "sweep race":
        return sweep_race(index, work)
    disk = work / f"trial{index}"
    if fault == "disk full" and not mount_tmpfs(disk):
        return {"fault": fault, "skipped": "mount -t tmpfs needs root"}
    run_dir = disk / "run"
    lr = f"{rng.choice([3e-4, 5e-4, 1e-3]):g}"
    flags = ["--env", "Catch-v0", "--num-workers", "2", "--envs-per-worker", "16",
             "--total-timesteps", str(total), "--checkpoint-interval", "5000",
             "--eval-interval", "20000", "--eval-episodes", "5", "--log-interval", "1",
             "--learning-rate", lr, "--seed", str(100 + index)]  # fmt: skip
    expected = {"learning_rate": float(lr), "seed": 100 + index, "total_timesteps": total,
                "envs_per_worker": 16}  # fmt: skip
    result = {"fault": fault, "lost": 0, "orphans": [], "attempts": 1, "restarted": False}
    # (the first attempt is the faulted one; a fault can come after the run finished)
    first = Attempt([*flags, "--run-dir", str(run_dir)])
    if not first.wait_for_pids():
        return {**result, "error": "the run did not start: " + first.output()[-300:]}
    time.sleep(rng.uniform(1.0, 12.0))  # the fault's random time
    before = checkpoint_state(run_dir / "checkpoint.pt")
    filler = None
    if fault == "SIGKILL worker":
        os.kill(first.pids[rng.choice(["worker 0", "worker 1"])], 9)
    elif fault == "SIGKILL main":
        os.kill(first.process.pid, 9)
    elif fault == "corrupt checkpoint":
        pass  # the run ends by itself; its last checkpoint is corrupted then
    elif fault in ("SIGTERM", "SIGINT"):
        # SIGINT as a terminal's Ctrl-C sends it, to the whole group; SIGTERM as `kill` does
        signum = 15 if fault == "SIGTERM" else 2
        if fault == "SIGINT":
            os.killpg(first.process.pid, signum)
        else:
            first.process.send_signal(signum)
    else:
        filler = fill(disk)
    first.process.wait(300)
    result["orphans"] += orphans(first.pids)
    result["exit"] = first.process.returncode
    last_line = (first.output().strip().splitlines() or [""])[-1]
    result["last_line"] = last_line[:160]
    finished_first = first.process.returncode == 0 and last_line.startswith("done:")
    expected_exit = {"SIGKILL worker": 1, "SIGKILL main": -9, "SIGTERM": 0, "SIGINT": 0,
                     "disk full": 1, "corrupt checkpoint": 0}[fault]  # fmt: skip
    hint = re.match(HINT, last_line)
    # a run the fault reached after it finished (or, for SIGKILL of the main process, that
    # could not say anything) is not held to the closing line
    result["ended_as_promised"] = finished_first or (
        first.process.returncode == expected_exit and (fault == "SIGKILL main" or bool(hint))
    )
    result["partial_files"] = len(list(run_dir.glob("*.tmp"))) if fault != "SIGKILL main" else 0
    after = checkpoint_state(run_dir / "checkpoint.pt")
    if before is not None and (after is None or after["step"] < before["step"]):
        result["lost"] += 1
    if filler is not None:
        filler.unlink()
    if fault == "corrupt checkpoint" and after is not None:
        result["ended_as_promised"] &= refuses_a_corrupt_checkpoint(run_dir / "checkpoint.pt", rng)
    state, finished = after, False
    while not finished and result["attempts"] < 5:  # resume to the end
        result["attempts"] += 1
        if state is None:  # the fault came before the first checkpoint: start again
            result["restarted"] = True
            shutil.rmtree(run_dir, ignore_errors=True)
            attempt = Attempt([*flags, "--run-dir", str(run_dir)])
        else:
            attempt = Attempt(["--resume", str(run_dir / "checkpoint.pt")])
        attempt.wait_for_pids()
        attempt.process.wait(600)
        result["orphans"] += orphans(attempt.pids)
        previous, state = state, checkpoint_state(run_dir / "checkpoint.pt")
        if previous is not None and (state is None or state["step"] < previous["step"]):
            result["lost"] += 1
        finished = attempt.process.returncode == 0 and state is not None and state["step"] >= total
    result["final_step"] = state["step"] if state else None
    result["reached"] = state is not None and state["step"] >= total
    result["same_flags"] = state is not None and all(
        state["args"].get(k) == v for k, v in expected.items()
    )
    if fault == "disk full":
        subprocess.run(["umount", "-l", str(disk)], check=False)
    return result


def refuses_a_corrupt_checkpoint(path: Path, rng: random.Random) -> bool:
    """Flip 64 bytes in the middle of the checkpoint: --resume must refuse it in one line, exit
    2, and leave it as it is; then its good bytes go back (a backup) for the run to go on."""
    good = path.read_bytes()
    start = len(good) // 2 + rng.randrange(-1000, 1000)
    bad = good[:start] + bytes(b ^ 0xFF for b in good[start : start + 64]) + good[start + 64 :]
    path.write_bytes(bad)
    refused = Attempt(["--resume", str(path)])
    refused.process.wait(120)
    lines = refused.output().strip().splitlines()
    ok = (refused.process.returncode == 2 and len(lines) == 1 and "is corrupt" in lines[0]
          and path.read_bytes() == bad)  # fmt: skip
    path.write_bytes(good)
    return ok


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--trials", type=int, default=20, help="runs to hit with a fault")
    parser.add_argument("--total-timesteps", type=int, default=60_000, help="each run's target")
    parser.add_argument("--seed", type=int, default=0, help="of the faults and their times")
    parser.add_argument("--faults", nargs="+", choices=FAULTS, default=list(FAULTS),
                        help="the faults to draw from")  # fmt: skip
    opts = parser.parse_args(argv)
    if opts.trials < 1 or opts.total_timesteps < 10_000:
        parser.error("--trials must be >= 1 and --total-timesteps >= 10000")
    rng = random.Random(opts.seed)
    results = []
    with tempfile.TemporaryDirectory() as work:
        for index in range(opts.trials):
            fault = opts.faults[index % len(opts.faults)]
            start = time.time()
            result = trial(index, fault, rng, opts.total_timesteps, Path(work))
            results.append(result)
            if "skipped" in result or "error" in result:
                print(f"trial {index:2d}: {fault:<14} {result.get('skipped') or result['error']}")
                continue
            print(
                f"trial {index:2d}: {fault:<14} exit {result['exit']:>3}, {result['attempts']} "
                f"attempts{' (restarted: no checkpoint yet)' if result['restarted'] else ''}, "
                f"final step {result['final_step']:,}, lost {result['lost']}, orphans "
                f"{len(result['orphans'])}, same flags {result['same_flags']}, ended as promised "
                f"{result['ended_as_promised']}, "
                f"{time.time() - start:.0f} s | {result['last_line']}",
                flush=True,
            )
    done = [r for r in results if "skipped" not in r]
    survived = sum(
        1 for r in done if r.get("reached") and r.get("same_flags") and r.get("ended_as_promised")
    )
    partial = sum(r.get("partial_files", 0) for r in done)
    lost = sum(r.get("lost", 0) for r in done)
    orphan_count = sum(len(r.get("orphans", [])) for r in done)
    errors = sum(1 for r in done if "error" in r)
    reached = sum(1 for r in done if r.get("reached") and r.get("same_flags"))
    every = "yes" if reached == len(done) else f"no ({len(done) - reached} did not)"
    print(f"\ntrials {len(done)} ({len(results) - len(done)} skipped); faults survived "
          f"{survived}/{len(done)}; checkpoints lost or unloadable {lost}; partial files "
          f"{partial}; orphan processes "
          f"{orphan_count}; every resumed run reached its target step with its original flags: "
          f"{every}; trials that could not start {errors}")  # fmt: skip
    for fault in FAULTS:
        count = sum(1 for r in done if r["fault"] == fault)
        if count:
            print(f"  {fault}: {count}")
    skipped = len(results) - len(done)
    if skipped:
        print(f"{skipped} disk-full trial(s) skipped: mounting a tmpfs needs root")
    ok = survived == len(done) and lost == partial == orphan_count == 0
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
