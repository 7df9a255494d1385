#!/usr/bin/env bash
# The campaign's leg on a lent 16-core machine: item c's runs 0 and 1 of each line (A3C FF, LPQ and
# GLPQ as run on Breakout, the plan's own sweep commands with --runs 2), six runs of 2 workers side
# by side for SECONDS, then stopped with SIGTERM (the sweeps pass SIGINT on to their runs, which
# save their checkpoints); each run folder is packed into OUT as one .tar.gz (unpacked at the repo
# root, the campaign resumes it), the sweeps' output into OUT/device_leg.log.
#
#     results/campaign/device_leg.sh SECONDS OUT     (PYTHON: the interpreter, default python3)
set -uo pipefail
seconds=$1
out=$2
mapfile -t commands < <("${PYTHON:-python3}" -m a3c_tools.campaign results/campaign/plan.toml --dry-run |
    grep -E 'sweep .* --out results/atari_figures/(fig6.9/Breakout/ff|fig7.8/Breakout/(lpq|glpq)_fig78) ' |
    sed 's/ --runs 3 / --runs 2 /' | awk '!seen[$0]++')
[ ${#commands[@]} -eq 3 ] || { echo "expected item c's 3 sweep commands, got ${#commands[@]}"; exit 1; }
pids=()
for c in "${commands[@]}"; do
    echo "$c"
    eval "exec ${PYTHON:-python3} ${c#python }" > "/tmp/sweep-${#pids[@]}.log" 2>&1 &
    pids+=($!)
done
sleep "$seconds"
kill -TERM "${pids[@]}" 2>/dev/null
for _ in $(seq 120); do
    alive=0
    for p in "${pids[@]}"; do kill -0 "$p" 2>/dev/null && alive=1; done
    [ $alive -eq 0 ] && break
    sleep 1
done
for d in results/atari_figures/*/Breakout/*/runs/run-*; do
    line=$(basename "$(dirname "$(dirname "$d")")")
    tar -czf "$out/$line-$(basename "$d").tar.gz" "$d"
    tail -n 2 "$d/stdout.log"
done
cat /tmp/sweep-*.log > "$out/device_leg.log"
ls -la "$out"
