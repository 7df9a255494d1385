#!/usr/bin/env bash
# The lines of tyro's error box for a bad flag of a3c_glpq.py (the script with the most flags),
# written to a pipe (80 columns): an unknown flag, a value outside a flag's choices, and for each
# numeric flag below a value of the wrong type (abc) and a near-miss typo of its name (NAMEx).
# Run from the repository root: bash results/tyro_errors/count.sh > results/tyro_errors/output.txt
set -u
lines() { python agents/a3c_glpq.py "$@" 2>&1 | wc -l; }
echo "unknown flag (--no-such-flag 1): $(lines --no-such-flag 1)"
echo "value outside a flag's choices (--activation tanh): $(lines --activation tanh)"
for f in seed total-timesteps num-workers time-limit learning-rate gamma rms-init grad-clip \
    prototypes-per-action competition-size prototype-init-bound p-start eval-interval \
    checkpoint-interval log-interval; do
    echo "--$f: wrong type $(lines --"$f" abc), near-miss typo $(lines --"${f}"x 1)"
done
