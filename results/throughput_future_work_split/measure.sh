#!/usr/bin/env bash
# Old (edb10f3) and new alternating, 3 rounds, the fast setting on Catch (K = 16, auto = bf16).
set -u
OUT="$(cd "$(dirname "$0")" && pwd)"  # this folder
. /work/venv/bin/activate
for round in 1 2 3; do
  (cd /tmp/old_main && PYTHONPATH=/tmp/old_main/agents python benchmarks/a3c_throughput.py --seconds 20 --envs-per-worker 16 --precision auto --no-baseline) > $OUT/old_round$round.txt 2>&1
  (cd /work/main && python benchmarks/a3c_throughput.py --seconds 20 --envs-per-worker 16 --precision auto --no-baseline) > $OUT/new_round$round.txt 2>&1
done
