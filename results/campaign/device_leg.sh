#!/usr/bin/env bash
# The campaign's leg on a lent 16-core machine: some runs of some Atari lines of the plan (each
# run's command exactly as the plan's sweep would launch it: `sweep ... --dry-run`), side by side,
# for SECONDS, then stopped with SIGINT (the scripts save their checkpoints); each run folder is
# packed into OUT as one .tar.gz, the runs' last lines into OUT/device_leg.log, and a row per
# line for results/campaign/SWEEPS.tsv (its item, the leg's start and end, this CPU) into
# OUT/SWEEPS.rows. A SIGTERM or Ctrl-C to this script stops the runs and packs them at once.
#
#     results/campaign/device_leg.sh SECONDS OUT [LINES] [RUNS]   (PYTHON: the interpreter)
#
# LINES: an extended regular expression of the lines' folders under results/atari_figures/,
# matched whole; RUNS: the run indices. Default: runs 0-2 of item b's two lines on Pong (item
# c's, d's and c2's LPQ on Breakout began in three earlier legs). Six runs fit: 12 workers, and 6
# packed folders of 5-11 MB each, under the 64 MiB that comes back. The machine starts without
# this machine's run folders (they are ignored files): a run begun here is resumed there from its
# checkpoint only if its folder is carried (the run tool's `carry`: with the wheels, 4 folders of
# about 12 MB fit its 64 MiB), and a run whose folder is not there starts there. Carry only runs
# that the campaign here will not reach while the leg runs. The campaign's sweeps resume the runs
# unpacked here from their checkpoints (a run's folder is all a sweep needs of it). Unpack at the
# repository root; a folder that came back replaces this machine's copy, which it continues:
#     for f in OUT/*.tar.gz; do d=$(tar -tzf "$f" | head -1 | cut -d/ -f1-7)
#         rm -rf "$d" && tar -xzf "$f"; done
#     cat OUT/SWEEPS.rows >> results/campaign/SWEEPS.tsv
set -uo pipefail +m  # +m: no job control, so `exec setsid` below does not fork and $! is the run
shopt -s nullglob
seconds=$1
out=$2
lines=${3:-'fig6.10/Pong/vf(1[.]0|0[.]5)'}
runs=${4:-0 1 2}
python=${PYTHON:-python3}
runs_re=$(printf '%04d|' $runs)
plan=$("$python" -m a3c_tools.campaign results/campaign/plan.toml --dry-run) ||
    { echo "the plan's dry run failed (above)"; exit 1; }
pattern="^python -m a3c_tools.sweep .* --out results/atari_figures/($lines) "
mapfile -t sweeps < <(grep -E "$pattern" <<< "$plan" | awk '!seen[$0]++')
commands=()
for s in "${sweeps[@]}"; do
    [[ $s == *" -- "* ]] && s=${s/ -- / --dry-run -- } || s="$s --dry-run"  # before the runs' flags
    listed=$(eval "$python ${s#python }") || { echo "the sweep's dry run failed: $s"; exit 1; }
    pattern="^python agents/.* --run-dir results/atari_figures/.*/runs/run-(${runs_re%|})$"
    mapfile -t -O ${#commands[@]} commands < <(grep -E "$pattern" <<< "$listed")
done
[ ${#commands[@]} -gt 0 ] || { echo "no run of the plan matches $lines, runs $runs"; exit 1; }
pids=()
dirs=()
finish() {  # stop the runs (SIGINT: each checkpoints), then pack them; also on SIGTERM or Ctrl-C
    trap - INT TERM
    for p in "${pids[@]}"; do kill -INT -- "-$p" 2>/dev/null; done  # each run's process group
    for _ in $(seq 120); do
        alive=0
        for p in "${pids[@]}"; do kill -0 "$p" 2>/dev/null && alive=1; done
        [ $alive -eq 0 ] && break
        sleep 1
    done
    for p in "${pids[@]}"; do  # its checkpoint is written whole or not at all (os.replace)
        kill -0 "$p" 2>/dev/null || continue
        echo "run $p still going after 120 s: killed"
        kill -KILL -- "-$p"
    done
    for d in "${dirs[@]}"; do
        # FIG-GAME-LINE-run-N
        name=$(echo "${d#results/atari_figures/}" | sed 's|/runs/|-|; s|/|-|g')
        tar -czf "$out/$name.tar.gz" "$d"
        tail -n 2 "$d/stdout.log" | tee -a "$out/device_leg.log"
    done
    ended=$(date +%s)
    mapfile -t folders < <(printf '%s\n' "${dirs[@]%/runs/*}" | awk '!seen[$0]++')  # the lines
    "$python" - "$started" "$ended" "${folders[@]}" > "$out/SWEEPS.rows" <<'ROWS'
import os, sys, time
from pathlib import Path
from a3c_tools.campaign import cpu_model, load_plan
started, ended, *folders = sys.argv[1:]
items = load_plan(Path("results/campaign/plan.toml").resolve())
stamp = lambda t: time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(int(t)))
for folder in folders:  # the first item that sweeps the line, as the campaign counts it
    item = next(i.id for i in items if any(str(s.out) == folder for s in i.sweeps))
    row = [item, folder, stamp(started), stamp(ended), str(int(ended) - int(started)), "0", "0"]
    print("\t".join([*row, cpu_model(), str(os.cpu_count())]))
ROWS
    cat "$out/SWEEPS.rows"
    ls -la "$out"
    exit 0
}
trap finish INT TERM
started=$(date +%s)
for c in "${commands[@]}"; do
    dir=${c##* --run-dir }
    if [ -f "$dir/checkpoint.pt" ]; then  # carried here: resumed, as the sweep would resume it
        script=${c#python }
        c="python ${script%% *} --resume $dir/checkpoint.pt"
    elif [ -e "$dir" ]; then
        echo "$dir exists here without a checkpoint: not run"
        continue
    fi
    echo "$c"
    dirs+=("$dir")
    mkdir -p "$dir"
    eval "exec setsid $python ${c#python }" >> "$dir/stdout.log" 2>> "$dir/stderr.log" &
    pids+=($!)
done
sleep "$seconds" &
wait $!  # a signal's trap runs at once, not after the sleep
finish
