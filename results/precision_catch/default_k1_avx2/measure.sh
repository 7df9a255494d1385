#!/bin/sh
# The default run (A3C FF on Catch-v0, K = 1, --precision auto) of the code before and after
# --precision auto became fp32 at K = 1 on every CPU, alternating in 3 rounds of 15 s.
# OLD: a copy of the tree before the change (git archive 697183e agents benchmarks catch_env).
# Run from the repository root: OLD=/tmp/oldtree sh results/precision_catch/default_k1_avx2/measure.sh
set -e
OUT=results/precision_catch/default_k1_avx2
for round in 1 2 3; do
    PYTHONPATH="$OLD:$OLD/agents" python "$OLD/benchmarks/a3c_throughput.py" --seconds 15 \
        --no-baseline --envs-per-worker 1 --precision auto > "$OUT/old_round$round.txt" 2>&1
    PYTHONPATH="$PWD:$PWD/agents" python benchmarks/a3c_throughput.py --seconds 15 \
        --no-baseline --envs-per-worker 1 --precision auto > "$OUT/new_round$round.txt" 2>&1
done
