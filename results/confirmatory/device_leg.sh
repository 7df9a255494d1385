#!/usr/bin/env bash
# The confirmatory study's leg on a lent GPU machine: some runs of some Catch lines of the plan,
# each line's runs as one batched program on the GPU (amendment 2 of PLAN.md), each run the plan's
# run i exactly (its sweep command from `campaign --dry-run`, with --runs cut to RUNS and
# `--backend batched --device $DEVICE` added). A batch's runs step together and finish together,
# so a line's RUNS must finish within the command's 10 minutes. Measured on an H200 in fp32
# (results/batched_throughput/COMMAND.txt), no line does: A3C FF's batch of 50 runs steps at
# 189 steps/s and c6's 35 GLPQ runs at 191-235, so 250,000 steps take 18-22 minutes. Size it from
# the measured rate (results/batched_throughput/h200_fp32.txt, run-steps/s at N runs: RUNS x
# 250,000 / rate(RUNS) plus about 30 s to build and evaluate must fit). A line cut off by its timeout leaves nothing (its
# checkpoints, 11 MB a run, do not fit in the 64 MiB that comes back); a finished line's
# results.csv, sweep.json, log.txt and each run's evaluations.csv and stdout.log are copied into
# OUT under their repository paths, and a row per line for SWEEPS.tsv into OUT/SWEEPS.rows.
#
#     results/confirmatory/device_leg.sh OUT SECONDS LINE=RUNS [LINE=RUNS ...]
#         (PYTHON: the interpreter; DEVICE: cuda by default, cpu to try it here; STEPS: each
#          run's budget, to try the script only: its runs are then not the plan's, never commit)
#
# LINE: a Catch line's folder under results/confirmatory/catch/ (ff_as_run, lpq_as_run, ...);
# SECONDS: the leg's wall-time cap, over all its lines (each line gets what is left). Back here,
# copy OUT's results/ into the confirmatory campaign's worktree (the sweep there then skips the
# runs, as it skips any run already in results.csv) and append OUT/SWEEPS.rows to its
# results/confirmatory/SWEEPS.tsv; refresh.sh brings both to main:
#     cp -r OUT/results "$WORKTREE"/ && cat OUT/SWEEPS.rows >> "$WORKTREE"/results/confirmatory/SWEEPS.tsv
#
# The machine lacks gymnasium and tyro: carry ".whl" (results/batched_throughput/device.sh's
# header says how it is made) and start with
#     python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade \
#         --target /tmp/site .whl/*.whl
#     export PYTHONPATH=/tmp/site:$PWD/agents:$PWD PYTHONUNBUFFERED=1 PYTHON=python3
set -uo pipefail
[ $# -ge 3 ] || { echo "usage: $0 OUT SECONDS LINE=RUNS [LINE=RUNS ...]"; exit 2; }
out=$1
seconds=$2
shift 2
python=${PYTHON:-python3}
device=${DEVICE:-cuda}
plan=$("$python" -m a3c_tools.campaign results/confirmatory/plan.toml --dry-run) ||
    { echo "the plan's dry run failed (above)"; exit 1; }
deadline=$(($(date +%s) + seconds))
rows=()
for pair in "$@"; do
    line=${pair%%=*}
    runs=${pair#*=}
    folder=results/confirmatory/catch/$line
    sweep=$(grep -E "^python -m a3c_tools.sweep .* --out $folder " <<< "$plan")
    [ -n "$sweep" ] || { echo "no Catch line $line in the plan"; exit 2; }
    planned=$(sed -E 's/.* --runs ([0-9]+) .*/\1/' <<< "$sweep")
    [[ $runs =~ ^[0-9]+$ ]] && [ "$runs" -ge 1 ] && [ "$runs" -le "$planned" ] ||
        { echo "$line: RUNS must be 1 to $planned (the plan's), not $runs"; exit 2; }
    sweep=$(sed -E "s/ --runs $planned / --runs $runs /; s/ -- / --backend batched --device $device -- /" \
        <<< "$sweep")
    [ -z "${STEPS:-}" ] || sweep=$(sed -E "s/ --total-timesteps [0-9]+ / --total-timesteps $STEPS /" \
        <<< "$sweep")
    left=$((deadline - $(date +%s)))
    [ $left -gt 30 ] || { echo "$line: no time left"; break; }
    started=$(date +%s)
    echo "$sweep   (at most ${left}s)"
    timeout --signal=INT --kill-after=60 "$left" $python ${sweep#python } || {
        echo "$line: the sweep did not finish (exit $?): nothing of it comes back"; continue; }
    ended=$(date +%s)
    for f in "$folder"/{results.csv,sweep.json,log.txt} "$folder"/runs/*/{evaluations.csv,stdout.log}; do
        [ -f "$f" ] && mkdir -p "$out/$(dirname "$f")" && cp "$f" "$out/$f"
    done
    rows+=("$folder $started $ended $sweep")
done
"$python" - "${rows[@]}" > "$out/SWEEPS.rows" <<'ROWS'
import csv, os, shlex, sys, time
from pathlib import Path
from a3c_tools.campaign import load_plan, ran_on
items = load_plan(Path("results/confirmatory/plan.toml").resolve())
stamp = lambda t: time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(int(t)))
for row in sys.argv[1:]:  # as the campaign's own SWEEPS.tsv rows (a3c_tools.campaign.log_sweep)
    folder, started, ended, sweep = row.split(" ", 3)
    item = next(i.id for i in items if any(str(s.out) == folder for s in i.sweeps))
    with open(Path(folder) / "results.csv") as f:
        done = sum(r["status"] == "ok" for r in csv.DictReader(f))
    print("\t".join([item, folder, stamp(started), stamp(ended), str(int(ended) - int(started)),
                     "0", str(done), ran_on(shlex.split(sweep)), str(os.cpu_count())]))
ROWS
cat "$out/SWEEPS.rows"
