r"""Benchmark figures of this working tree against a commit's, in the same run: each command runs
in a git worktree of the commit and in this tree by turns, round after round (--rounds), so that
a shared machine's drifts fall on both alike; a measure's figure is the number its --pattern
captures (the first group, commas allowed) in its command's output. Measures that share a
command share its runs.

    python benchmarks/against_commit.py BASE --rounds 3 --out FILE \
        --measure "process K=1" "^a3c_ff: ([\d,.]+) steps/s" \
            "python benchmarks/a3c_throughput.py --seconds 15 --no-baseline" [--measure ...]

Each command runs with its tree first on PYTHONPATH (the tree's catch_env and agents packages
shadow the installed ones). Prints, per measure, both trees' figures by round, their means and
this tree's ratio to the commit's.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def output(command: str, tree: Path) -> subprocess.CompletedProcess:
    """The command's run in `tree`, its tree's packages first on the path."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), str(tree / "agents")])}
    return subprocess.run(command, shell=True, cwd=tree, env=env, capture_output=True, text=True)


def shown(x: float) -> str:
    return f"{x:,.0f}" if abs(x) >= 100 else f"{x:.3g}"


def figure(result: subprocess.CompletedProcess, pattern: str, tree: Path) -> float:
    """The number `pattern` captures in a command's output."""
    for line in result.stdout.splitlines():
        if match := re.search(pattern, line):
            return float(match.group(1).replace(",", ""))
    raise SystemExit(f"error: {result.args!r} in {tree} printed no line matching {pattern!r} "
                     f"(exit {result.returncode}): {result.stderr.strip()[-500:]}")  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("base", help="the commit to compare with")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--measure", nargs=3, action="append", required=True,
                        metavar=("NAME", "PATTERN", "COMMAND"))  # fmt: skip
    parser.add_argument("--out", help="also write the report to this file")
    args = parser.parse_args()
    if args.out and not Path(args.out).resolve().parent.is_dir():  # before the runs, not after
        parser.error(f"--out {args.out}: its folder does not exist")
    lines: list[str] = []

    def report(line: str) -> None:
        print(line, flush=True)
        lines.append(line)

    head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, text=True,
                          capture_output=True).stdout.strip()  # fmt: skip
    dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                           text=True, capture_output=True).stdout.strip()  # fmt: skip
    with tempfile.TemporaryDirectory() as scratch:
        base = Path(scratch) / "base"
        subprocess.run(["git", "worktree", "add", "--detach", "-q", str(base), args.base],
                       cwd=ROOT, check=True)  # fmt: skip
        try:
            report(f"# this tree ({head}{' + changes' if dirty else ''}) against {args.base}, "
                   f"{args.rounds} rounds by turns")  # fmt: skip
            figures = {name: {"base": [], "this": []} for name, _, _ in args.measure}
            commands = list(dict.fromkeys(command for _, _, command in args.measure))
            for _ in range(args.rounds):
                for command in commands:
                    for label, tree in (("base", base), ("this", ROOT)):
                        result = output(command, tree)
                        for name, pattern, measured in args.measure:
                            if measured == command:
                                figures[name][label].append(figure(result, pattern, tree))
            for name, _, _ in args.measure:
                rounds = {k: ", ".join(map(shown, v)) for k, v in figures[name].items()}
                mean = {k: statistics.mean(v) for k, v in figures[name].items()}
                report(f"{name}: {args.base} {rounds['base']} (mean {shown(mean['base'])}); this "
                       f"tree {rounds['this']} (mean {shown(mean['this'])}); ratio "
                       f"{mean['this'] / mean['base']:.3f}")  # fmt: skip
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base)], cwd=ROOT)
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
