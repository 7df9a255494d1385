#!/usr/bin/env bash
# The measurements of results/throughput_package (see COMMAND.txt): run from the repository root
# with every other job stopped. OLD is a checkout of the code before the run machinery became a
# package (git worktree add /tmp/old_main 528cc92); both use the same virtual environment.
set -euo pipefail
OLD=${OLD:-/tmp/old_main}
OUT=results/throughput_package
NEW=$PWD
# 1. before/after, alternating, 3 rounds: the fast setting (K = 16, bf16) and K = 1 (bf16-learn),
#    each next to the plain loop of the same run
for round in 1 2 3; do
  (cd "$OLD" && python benchmarks/a3c_throughput.py --seconds 15 --envs-per-worker 16 1 \
      --precision auto) > "$OUT/before_after_old_$round.txt" 2>&1
  (cd "$NEW" && python benchmarks/a3c_throughput.py --seconds 15 --envs-per-worker 16 1 \
      --precision auto) > "$OUT/before_after_new_$round.txt" 2>&1
done
# 2. the activation replay on and off, alternating within each of 3 rounds
python benchmarks/a3c_throughput.py --seconds 15 --rounds 3 --envs-per-worker 16 1 \
    --precision auto --replay on off --no-baseline > "$OUT/replay_ab.txt" 2>&1
# 3. glibc keeping freed memory (the workers' default) or not, alternating, 3 rounds
for round in 1 2 3; do
  python benchmarks/a3c_throughput.py --seconds 15 --envs-per-worker 16 1 --precision auto \
      --no-baseline > "$OUT/malloc_keep_$round.txt" 2>&1
  python benchmarks/a3c_throughput.py --seconds 15 --envs-per-worker 16 1 --precision auto \
      --no-baseline --default-malloc > "$OUT/malloc_default_$round.txt" 2>&1
done
