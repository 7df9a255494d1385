#!/usr/bin/env bash
# Regenerates every committed file that the campaign's new runs feed, so that a commit of its
# results.csv rows carries them: the claims page and its forest plot, the chapter 8 summary
# (summary.txt, curves.csv, curves.png) and PROGRESS.md. Tests hold the claims page and the
# summary to their inputs (test_thesis_claims, test_tools_analysis). From the repository root:
#     bash results/campaign/refresh.sh && git add docs results
set -euo pipefail
python -m a3c_tools.thesis_claims -o docs/claims.md
python -m a3c_tools.future_work_summary > results/future_work_catch/summary.txt
python -m a3c_tools.campaign results/campaign/plan.toml --status
python -m a3c_tools.confirmatory results/confirmatory/plan.toml --check
