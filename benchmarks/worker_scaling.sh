#!/usr/bin/env bash
# The fast setting's speed on Breakout as the workers grow: a3c_ff.py at K = 16 envs per worker,
# --precision auto (bf16 at K = 16), ale-py's native vector env with one emulator thread and one
# torch thread per worker; one a3c_throughput.py measurement per worker count, each run alone on
# the machine. Prints each measurement, then a table of steps/s and steps/s per worker.
#
#     benchmarks/worker_scaling.sh [SECONDS] [WORKERS ...]   (default: 20 s; 1 2 4 8 16; PYTHON: the
#                                                           interpreter, default python3)
set -euo pipefail
seconds=${1:-20}
shift || true
counts=("$@")
[ ${#counts[@]} -gt 0 ] || counts=(1 2 4 8 16)
here=$(cd "$(dirname "$0")" && pwd)
lscpu | grep -E '^(Model name|CPU\(s\)|Thread|Core|Socket)' || true
summary=""
for n in "${counts[@]}"; do
    out=$("${PYTHON:-python3}" "$here/a3c_throughput.py" --env BreakoutNoFrameskip-v4 --envs-per-worker 16 \
        --precision auto --seconds "$seconds" --rounds 1 --no-baseline --eval-episodes 1 \
        --num-workers "$n" 2>&1) || echo "a3c_throughput.py failed at $n workers (exit $?)"
    echo "$out"
    sps=$(echo "$out" | awk '$1 == "a3c_ff" && $2 == "16" {print $6}' | tail -1)
    summary+="$n ${sps:-?}"$'\n'
done
echo
echo "workers  steps/s  steps/s per worker  (BreakoutNoFrameskip-v4, a3c_ff.py, K = 16, auto, native)"
echo -n "$summary" | awk '{sps = $2; gsub(",", "", sps); printf "%7d  %7s  %18.0f\n", $1, $2, sps / $1}'
