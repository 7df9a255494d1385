#!/usr/bin/env bash
# The first reproduction of the thesis's Catch learning-rate sweeps (issue 6, point 4):
# A3C FF, GLPQ (hot, 1/tau loss correction: its default), LPQ, LWS, SS and WW, each run
# 250k steps with 1 worker, learning rate log-uniform in [1e-5, 1e-2] (the range the thesis
# averages over), scored by the mean of its final 5 evaluations. Evaluations come every 12,500
# steps, the thesis's 50,000-in-1M scaled to the budget: 20 per run, so that the final 5 cover
# the last 20% of training, as in the thesis (every 50,000 steps would make them 50k-250k,
# nearly the whole run).
#
#   bash results/sweep_catch/reproduce.sh            # RUNS=8 per configuration
#   RUNS=16 bash results/sweep_catch/reproduce.sh    # more runs: the first 8 are kept
#
# Round-robin: every configuration gets 2 more runs per round (2 single-worker runs at a time
# on a 2-core machine), so a stopped reproduction has covered the configurations evenly.
# Started again, each sweep skips the runs already in its results.csv (sweep.py resumes).
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=results/sweep_catch
RUNS=${RUNS:-8}
STEPS=${STEPS:-250000}
CONFIGS=(a3c_ff a3c_glpq a3c_lpq a3c_lws a3c_ss a3c_ww)
for ((runs = 2; runs <= RUNS; runs += 2)); do
  for script in "${CONFIGS[@]}"; do
    python -m a3c_tools.sweep "agents/$script.py" --out "$OUT/$script" --runs "$runs" \
      --total-timesteps "$STEPS" --sample learning-rate=loguniform:1e-5:1e-2 \
      -- --eval-interval $((STEPS / 20))
  done
done
TABLES=()
for script in "${CONFIGS[@]}"; do TABLES+=("$OUT/$script/results.csv"); done
python -m a3c_tools.plot_sweep "${TABLES[@]}" --out "$OUT/sweep_catch.png" \
  --labels "A3C FF" "GLPQ hot (corr.)" LPQ LWS SS WW \
  --title "Catch-v0 learning-rate sweeps, $STEPS steps per run, 1 worker"
