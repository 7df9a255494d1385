#!/usr/bin/env bash
# Old and new alternating, 3 rounds, the fast setting on Catch (K = 16, auto = bf16 here).
# OLD: a checkout of the code before (git worktree add /tmp/old_main edb10f3); run from the
# repository root with the project's Python active.
set -u
OUT="$(cd "$(dirname "$0")" && pwd)"  # this folder
NEW="$(cd "$OUT/../.." && pwd)"
OLD=${OLD:-/tmp/old_main}
for round in ${ROUNDS:-1 2 3}; do
    (cd "$OLD" && PYTHONPATH="$OLD/agents" python benchmarks/a3c_throughput.py --seconds 20 \
        --envs-per-worker 16 --precision auto --no-baseline) > "$OUT/old_round$round.txt" 2>&1
    (cd "$NEW" && python benchmarks/a3c_throughput.py --seconds 20 --envs-per-worker 16 \
        --precision auto --no-baseline) > "$OUT/new_round$round.txt" 2>&1
done
