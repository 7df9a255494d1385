#!/usr/bin/env bash
# Regenerates every committed file that the campaign's new runs feed, so that a commit of its
# results.csv rows carries them: the claims page and its forest plot, the chapter 8 summary
# (summary.txt, curves.csv, curves.png) and PROGRESS.md. Tests hold the claims page and the
# summary to their inputs (test_thesis_claims, test_tools_analysis). From the repository root:
#     bash results/campaign/refresh.sh [FROM] && git add docs results
# FROM: a copy of the repository the campaign runs in (a git worktree pinned at a commit, so
# that edits here never reach a run in flight): first SWEEPS.tsv, and every line whose
# results.csv there holds more rows than here (the campaign only adds rows), with its
# sweep.json and its runs' evaluations.csv files (in runs/, not committed, but read by the
# summary to gather curves.csv), are copied from it, so that no curve is lost with its folder.
set -euo pipefail
if [ $# -ge 1 ]; then
    from=$(cd "$1" && pwd)
    cp "$from/results/campaign/SWEEPS.tsv" results/campaign/SWEEPS.tsv
    while IFS= read -r table; do
        line=$(dirname "${table#"$from"/}")
        here=0
        [ -f "$line/results.csv" ] && here=$(wc -l < "$line/results.csv")
        [ "$(wc -l < "$table")" -gt "$here" ] || continue
        mkdir -p "$line"
        cp "$table" "$line/results.csv"
        [ -f "$from/$line/sweep.json" ] && cp "$from/$line/sweep.json" "$line/sweep.json"
        for csv in "$from/$line"/runs/*/evaluations.csv; do
            [ -f "$csv" ] || continue
            run=$(basename "$(dirname "$csv")")
            mkdir -p "$line/runs/$run" && cp "$csv" "$line/runs/$run/evaluations.csv"
        done
    done < <(find "$from/results" -name results.csv -not -path "*/runs/*")
fi
python -m a3c_tools.thesis_claims -o docs/claims.md
python -m a3c_tools.future_work_summary > results/future_work_catch/summary.txt
python -m a3c_tools.campaign results/campaign/plan.toml --status
python -m a3c_tools.confirmatory results/confirmatory/plan.toml --check
