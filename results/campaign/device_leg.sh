#!/usr/bin/env bash
# The campaign's leg on a lent 16-core machine: runs 0 and 1 of some Atari lines of the plan (the
# plan's own sweep commands with --runs 2), side by side, for SECONDS, then stopped with SIGTERM
# (the sweeps pass SIGINT on to their runs, which save their checkpoints); each run folder is
# packed into OUT as one .tar.gz, the sweeps' output into OUT/device_leg.log.
#
#     results/campaign/device_leg.sh SECONDS OUT [LINES]     (PYTHON: the interpreter, python3)
#
# LINES: an extended regular expression of the lines' folders under results/atari_figures/,
# matched whole; default: item d's LWS and WW on Breakout and item c2's text LPQ (6 runs: 12
# workers, and 6 packed folders of about 10 MB each, under the 64 MiB that comes back). Pick
# lines none of whose runs 0-1 exist here: the machine starts without this machine's run
# folders (they are ignored files), so a line begun here would begin again there. Unpack at the
# repository root only the folders that are not here (a run folder is one run's, whole):
#     for f in OUT/*.tar.gz; do d=$(tar -tzf "$f" | head -1 | cut -d/ -f1-7)
#         if [ -e "$d" ]; then echo "kept $d, not $f"; else tar -xzf "$f"; fi; done
set -uo pipefail
shopt -s nullglob
seconds=$1
out=$2
lines=${3:-'fig6.9/Breakout/(lws|ww)|fig7.8/Breakout/lpq'}
mapfile -t commands < <("${PYTHON:-python3}" -m a3c_tools.campaign results/campaign/plan.toml --dry-run |
    grep -E "^python -m a3c_tools.sweep .* --out results/atari_figures/($lines) " |
    sed 's/ --runs 3 / --runs 2 /' | awk '!seen[$0]++')
[ ${#commands[@]} -gt 0 ] || { echo "no sweep of the plan matches $lines"; exit 1; }
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
for d in results/atari_figures/*/*/*/runs/run-*; do
    [[ $d =~ ^results/atari_figures/($lines)/runs/ ]] || continue  # only the lines run here
    name=$(echo "${d#results/atari_figures/}" | sed 's|/runs/|-|; s|/|-|g')  # FIG-GAME-LINE-run-i
    tar -czf "$out/$name.tar.gz" "$d"
    tail -n 2 "$d/stdout.log"
done
cat /tmp/sweep-*.log > "$out/device_leg.log"
ls -la "$out"
