#!/usr/bin/env bash
# Three commits alternating, 4 rounds, the fast setting on Catch (K = 16, auto = bf16 here), each
# with its own catch_env and agents (PYTHONPATH). Worktrees first, from the repository root:
#   git worktree add /tmp/pre_snap c9f544f   # before the worker-taken evaluations/checkpoints
#   git worktree add /tmp/pre_fp 757159c     # before the replay's input fingerprint
# Run from the repository root (HEAD) with the project's Python active.
set -u
OUT="$(cd "$(dirname "$0")" && pwd)"
HEAD_DIR="$(cd "$OUT/../../.." && pwd)"
for round in 1 2 3 4; do
    for name in pre_snap pre_fp head; do
        dir=/tmp/$name
        [ "$name" = head ] && dir=$HEAD_DIR
        (cd "$dir" && PYTHONPATH="$dir/agents:$dir" python benchmarks/a3c_throughput.py --seconds 20 \
            --envs-per-worker 16 --precision auto --no-baseline) > "$OUT/${name}_$round.txt" 2>&1
    done
done
