#!/usr/bin/env bash
# Issue 12, point 4: the thesis's GLPQ as it was run, added to the first reproduction
# (reproduce.sh) at its budget: the same 8 learning rates and run seeds (sweep seed 1, learning
# rate log-uniform in [1e-5, 1e-2]), 250k steps per run, 1 worker, an evaluation every 12,500.
#
# Lines (thesis-figures-as-run.md): Figure 7.6's GLPQ cold (preset 94), hot (126) and searing
# (131) as run: the code's relative distance (--mu-form code) and the 1/tau correction dividing
# the whole policy loss, entropy included (--tau-loss-scope policy-and-entropy); lambda_V 0.5.
# Figure 7.7 compares hot with LPQ (preset 100: tau = 1, which a3c_lpq.py computes), whose row
# reproduce.sh already has. A3C FF as run (preset 13) most likely had lambda_V = 1.0 (inferred):
# the a3c_ff_vf1 row; reproduce.sh's A3C FF row has the text's 0.5.
#
#   bash results/sweep_catch/reproduce_as_run.sh                          # here, resumable
#   OUT=/tmp/sweeps SWEEP_CPUS=8 bash results/sweep_catch/reproduce_as_run.sh   # 16+ cores
#
# The four sweeps run side by side, each with SWEEP_CPUS single-worker runs at a time (default
# 1: four runs on the machine at once).
set -euo pipefail
cd "$(dirname "$0")/../.."
OUT=${OUT:-results/sweep_catch}
RUNS=${RUNS:-8}
STEPS=${STEPS:-250000}
SWEEP_CPUS=${SWEEP_CPUS:-1}
AS_RUN_GLPQ="--mu-form code --tau-loss-scope policy-and-entropy"
declare -A LINES=(
  [a3c_glpq_code_cold]="a3c_glpq --temperature cold $AS_RUN_GLPQ"
  [a3c_glpq_code_hot]="a3c_glpq --temperature hot $AS_RUN_GLPQ"
  [a3c_glpq_code_searing]="a3c_glpq --temperature searing $AS_RUN_GLPQ"
  [a3c_ff_vf1]="a3c_ff --vf-coef 1.0"
)
for name in "${!LINES[@]}"; do
  read -r script flags <<<"${LINES[$name]}"
  # shellcheck disable=SC2086  # the flags split into words
  python -m a3c_tools.sweep "agents/$script.py" --out "$OUT/$name" --runs "$RUNS" \
    --total-timesteps "$STEPS" --sample learning-rate=loguniform:1e-5:1e-2 \
    --cpus "$SWEEP_CPUS" -- --eval-interval $((STEPS / 20)) $flags &
done
wait
