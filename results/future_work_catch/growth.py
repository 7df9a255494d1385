"""What --prototype-growth did in each run: its growth steps, prototypes pruned and grown.

    cd results/future_work_catch && python growth.py > growth.txt

Reads the lines that a growth step which changes anything prints ("prototype growth at step
...: pruned for actions [...], grown for [...]; active per action [...]") from each run's
stdout.log (runs/, written by the sweep, not committed: run the configurations first).
"""

import ast
import csv
import re
from pathlib import Path

HERE = Path(__file__).resolve().parent
LINE = re.compile(
    r"prototype growth at step ([\d,]+): pruned for actions (\[[^\]]*\]), grown for (\[[^\]]*\]);"
    r" active per action (\[[^\]]*\])"
)

print("config       run       growth steps that changed something   pruned   grown   "
      "active per action at the end (the defaults: 16 at the start, 32 slots)")  # fmt: skip
for config in ("lpq_growth", "glpq_growth"):
    if not (HERE / config / "results.csv").is_file():
        continue
    with open(HERE / config / "results.csv", newline="") as f:
        finished = sorted(r["run_id"] for r in csv.DictReader(f) if r["status"] == "ok")
    for run_id in finished:
        log = HERE / config / "runs" / run_id / "stdout.log"
        steps = [m for m in map(LINE.search, log.read_text().splitlines()) if m]
        pruned = sum(len(ast.literal_eval(m[2])) for m in steps)
        grown = sum(len(ast.literal_eval(m[3])) for m in steps)
        active = steps[-1][4] if steps else "unchanged"
        print(f"{config:12} {run_id}  {len(steps):37d}   {pruned:6d}   {grown:5d}   {active}")
