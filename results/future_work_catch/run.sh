#!/usr/bin/env bash
# The thesis's future work (chapter 8, issue 28) on Catch at the fast setting: each idea against
# the thesis's version of the same script, 5 seeds per configuration (sweep.py run seeds 1, 1001,
# ..., 4001: run i has the same seed in every configuration, so runs pair up), 1M steps,
# 2 workers x 16 envs (--envs-per-worker 16, the fast setting), one run at a time on 2 cores.
# Resumable: each sweep skips the runs already in its results.csv.
#   bash results/future_work_catch/run.sh            # every configuration
#   bash results/future_work_catch/run.sh glpq_data  # some of them
#   RUNS=15 bash results/future_work_catch/run.sh lpq lpq_growth  # more runs (as committed)
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=results/future_work_catch
RUNS=${RUNS:-5}
FAST=(--envs-per-worker 16 --num-workers 2)
declare -A SCRIPT  # each idea's script (agents/future_work/) against the thesis's
SCRIPT[lpq]=a3c_lpq
SCRIPT[lpq_value]=future_work/a3c_lpq_value_head
SCRIPT[lpq_data]=future_work/a3c_lpq_data_init
SCRIPT[lpq_growth]=future_work/a3c_lpq_growth
SCRIPT[glpq]=a3c_glpq
SCRIPT[glpq_value]=future_work/a3c_glpq_value_head
SCRIPT[glpq_data]=future_work/a3c_glpq_data_init
SCRIPT[glpq_growth]=future_work/a3c_glpq_growth
SCRIPT[lws]=a3c_lws
SCRIPT[lws_online]=future_work/a3c_lws_online
ORDER=(glpq glpq_data glpq_value glpq_growth lpq lpq_data lpq_value lpq_growth lws lws_online)
for name in "${@:-${ORDER[@]}}"; do
    [[ -n "${SCRIPT[$name]:-}" ]] || { echo "unknown configuration $name; valid: ${ORDER[*]}" >&2; exit 2; }
    python -m a3c_tools.sweep "agents/${SCRIPT[$name]}.py" --out "$OUT/$name" --runs "$RUNS" \
        --total-timesteps 1000000 -- "${FAST[@]}"
done
