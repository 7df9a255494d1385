"""One benchmark figure of this working tree against a commit's, in the same run: each command
runs in a git worktree of the commit and in this tree by turns, --rounds times, so that a shared
machine's drifts fall on both alike; the figure is the number the command prints that --pattern
captures (its first group, commas allowed).

    python benchmarks/against_commit.py BASE --rounds 3 --out FILE \\
        --measure "process K=1" "^a3c_ff: ([\\d,.]+) steps/s" \\
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


def figure(command: str, pattern: str, tree: Path) -> float:
    """The number `pattern` captures in the command's output, run in `tree`."""
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(tree), str(tree / "agents")])}
    result = subprocess.run(command, shell=True, cwd=tree, env=env, capture_output=True,
                            text=True)  # fmt: skip
    for line in result.stdout.splitlines():
        if match := re.search(pattern, line):
            return float(match.group(1).replace(",", ""))
    raise SystemExit(f"error: {command!r} in {tree} printed no line matching {pattern!r} "
                     f"(exit {result.returncode}): {result.stderr.strip()[-500:]}")  # fmt: skip


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("base", help="the commit to compare with")
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--measure", nargs=3, action="append", required=True,
                        metavar=("NAME", "PATTERN", "COMMAND"))  # fmt: skip
    parser.add_argument("--out", help="also write the report to this file")
    args = parser.parse_args()
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
            for name, pattern, command in args.measure:
                figures: dict[str, list[float]] = {"base": [], "this": []}
                for _ in range(args.rounds):
                    figures["base"].append(figure(command, pattern, base))
                    figures["this"].append(figure(command, pattern, ROOT))
                shown = {k: ", ".join(f"{x:,.0f}" for x in v) for k, v in figures.items()}
                mean = {k: statistics.mean(v) for k, v in figures.items()}
                report(f"{name}: {args.base} {shown['base']} (mean {mean['base']:,.0f}); this "
                       f"tree {shown['this']} (mean {mean['this']:,.0f}); ratio "
                       f"{mean['this'] / mean['base']:.3f}")  # fmt: skip
        finally:
            subprocess.run(["git", "worktree", "remove", "--force", str(base)], cwd=ROOT)
    if args.out:
        Path(args.out).write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
