"""What the dynamic prototypes did in each run of a3c_lpq_growth.py and a3c_glpq_growth.py
(agents/future_work/): its growth steps, prototypes pruned and grown.

    python -m a3c_tools.future_work_growth > results/future_work_catch/growth.txt

Reads the lines that a growth step which changes anything prints ("prototype growth at step
...: pruned for actions [...], grown for [...]; active per action [...]") from each run's
stdout.log (FOLDER/CONFIG/runs/, written by the sweep, not committed: run the configurations
first).
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

from a3c_tools import run_main
from a3c_tools.future_work_runs import folder_argument
from a3c_tools.paired import read_rows

CONFIGS = ("lpq_growth", "glpq_growth")
LINE = re.compile(
    r"prototype growth at step ([\d,]+): pruned for actions (\[[^\]]*\]), grown for (\[[^\]]*\]);"
    r" active per action (\[[^\]]*\])"
)
HEADER = ("config       run       growth steps that changed something   pruned   grown   "
          "active per action at the end (the defaults: 16 at the start, 32 slots)")  # fmt: skip


def configs_run(folder: Path) -> list[str]:
    """The growth configurations that have run in folder (a results.csv)."""
    return [config for config in CONFIGS if (folder / config / "results.csv").is_file()]


def growth_rows(folder: Path) -> list[str]:
    """One line per finished run of each growth configuration in folder."""
    rows = []
    for config in configs_run(folder):
        finished = sorted(r["run_id"] for r in read_rows(folder / config) if r["status"] == "ok")
        for run_id in finished:
            log = folder / config / "runs" / run_id / "stdout.log"
            steps = [m for m in map(LINE.search, log.read_text().splitlines()) if m]
            pruned = sum(len(ast.literal_eval(m[2])) for m in steps)
            grown = sum(len(ast.literal_eval(m[3])) for m in steps)
            active = steps[-1][4] if steps else "unchanged"
            rows.append(
                f"{config:12} {run_id}  {len(steps):37d}   {pruned:6d}   {grown:5d}   {active}"
            )
    return rows


def main(argv: list[str] | None = None) -> int:
    about = "Growth steps, prototypes pruned and grown, per run."
    folder = folder_argument("future_work_growth", about, argv, configs_run)
    print("\n".join([HEADER, *growth_rows(folder)]))
    return 0


if __name__ == "__main__":
    run_main(main)
