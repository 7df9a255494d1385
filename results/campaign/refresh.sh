#!/usr/bin/env bash
# Regenerates every committed file that the campaigns' new runs feed (this plan's and the
# confirmatory study's, results/confirmatory/plan.toml), so that a commit of their results.csv
# rows carries them: the claims page and its forest plot, the chapter 8 summary (summary.txt,
# curves.csv, curves.png) and each plan's PROGRESS.md. Tests hold the claims page and the
# summary to their inputs (test_thesis_claims, test_tools_analysis). From the repository root:
#     bash results/campaign/refresh.sh [FROM] && git add docs results
# FROM: a copy of the repository the campaign runs in (a git worktree pinned at a commit, so
# that edits here never reach a run in flight): first each plan's SWEEPS.tsv where FROM's is
# ahead, and every line whose
# results.csv there holds more rows than here (the campaign only adds rows), with its
# sweep.json and its runs' evaluations.csv files (in runs/, not committed, but read by the
# summary to gather curves.csv), are copied from it, so that no curve is lost with its folder;
# the confirmatory study's Atari figures are drawn there first and copied whole (each line's
# kept evaluations.csv, the figure's tables and drawing); its PROGRESS.md is written there, by
# FROM's own tool (which reads its own checkout), so that it counts the begun runs' steps.
set -euo pipefail
if [ $# -ge 1 ]; then
    from=$(cd "$1" && pwd)
    for plan in campaign confirmatory; do  # a log only grows: the longer (or newer) copy wins
        log=results/$plan/SWEEPS.tsv
        [ -f "$from/$log" ] || continue
        if [ ! -f "$log" ] || [ "$(wc -l < "$from/$log")" -gt "$(wc -l < "$log")" ] ||
            { [ "$(wc -l < "$from/$log")" -eq "$(wc -l < "$log")" ] && [ "$from/$log" -nt "$log" ]; }; then
            cp "$from/$log" "$log"
        fi
    done
    # the confirmatory study's Atari figures drawn again there, so that each line's kept
    # evaluations.csv holds the curve of every run whose folder is there now (a run folder is
    # not committed and goes with its machine), not only of runs whose sweep has ended
    for figure in "$from"/results/confirmatory/atari/fig*/; do
        [ -d "$figure" ] || continue
        python -m a3c_tools.atari_figures "$(basename "$figure")" \
            --out "$from/results/confirmatory/atari" --plot-only > /dev/null
        for kept in "$figure"*/*/evaluations.csv "$figure"results.csv "$figure"curves.csv \
            "$figure$(basename "$figure").png"; do
            here=${kept#"$from"/}
            if [ -f "$kept" ]; then mkdir -p "$(dirname "$here")" && cp "$kept" "$here"; fi
        done
    done
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
if [ $# -ge 1 ]; then  # by FROM's tool, where the begun runs' checkpoints are: counted too
    (cd "$from" && PYTHONPATH="$from/agents:$from" \
        python -m a3c_tools.campaign results/confirmatory/plan.toml --status > /dev/null)
    cp "$from/results/confirmatory/PROGRESS.md" results/confirmatory/PROGRESS.md
else
    python -m a3c_tools.campaign results/confirmatory/plan.toml --status > /dev/null
fi
python -m a3c_tools.confirmatory results/confirmatory/plan.toml --check
