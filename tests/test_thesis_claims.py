"""Tests of a3c_tools.thesis_claims (docs/claims.md from the committed results): the page holds
what the script makes of the data, the verdict rule on hand-made intervals, the paired bootstrap
against known samples, and the handling of lines not run yet."""

import csv

import numpy as np
import pytest
from a3c_tools import thesis_claims as claims  # noqa: E402
from conftest import ROOT, run_main


def test_the_claims_page_holds_what_the_committed_results_give():
    with open(claims.CLAIMS, "rb") as f:
        page = claims.render(claims.tomllib.load(f))
    assert (ROOT / "docs" / "claims.md").read_text() == page, (
        "docs/claims.md is stale: python -m a3c_tools.thesis_claims -o docs/claims.md"
    )


def test_the_check_option_fails_on_a_stale_page(tmp_path):
    stale = tmp_path / "claims.md"
    stale.write_text("# an old page\n")
    done = run_main(claims.main, ["--check", str(stale)])
    assert done.returncode == 1 and "is stale" in done.stdout


def test_every_claim_names_its_place_form_and_evidence_and_its_lines_exist_or_a_command():
    with open(claims.CLAIMS, "rb") as f:
        data = claims.tomllib.load(f)
    rows = [claim for section in data["section"] for claim in section["claim"]]
    assert len(rows) >= 25
    for claim in rows:
        assert claim["claim"] and claim["where"] and claim["form"] and claim["thesis"]
        if "baseline" in claim:
            assert claim["expect"] in ("better", "worse", "comparable")
            assert claim["command"] and len(claim["names"]) == 2
        else:
            assert claim["ours"] and claim["verdict"]
    wheres = " ".join(claim["where"] for claim in rows)
    for figure in ("6.3", "6.5", "6.6", "6.7", "6.8", "7.1", "7.2", "7.3", "7.5", "7.6", "7.7",
                   "6.9", "6.10", "7.8", "A.1", "A.2", "A.3", "C.1", "Chapter 8"):  # fmt: skip
        assert figure in wheres, figure


@pytest.mark.parametrize(
    ("expect", "effect", "low", "high", "verdict"),
    [
        ("better", 0.10, 0.02, 0.20, "reproduced"),
        ("better", -0.10, -0.20, -0.02, "contradicted"),
        ("worse", -0.10, -0.20, -0.02, "reproduced"),
        ("worse", 0.10, 0.02, 0.20, "contradicted"),
        ("comparable", 0.01, -0.04, 0.04, "reproduced"),
        ("comparable", 0.20, 0.10, 0.30, "contradicted"),
        ("comparable", 0.05, -0.02, 0.12, "inconclusive"),
    ],
)
def test_verdicts_follow_the_interval_and_the_claimed_direction(expect, effect, low, high, verdict):
    assert claims.verdict(expect, effect, low, high, 8).startswith(verdict)


def test_an_inconclusive_verdict_states_the_runs_that_would_decide_it():
    # half-width 0.1 against an effect of 0.05: the interval must shrink 2x, so 4x the runs
    assert claims.verdict("better", 0.05, -0.05, 0.15, 8) == (
        "inconclusive: about 32 runs per line would decide it"
    )
    assert "would not decide it" in claims.verdict("better", 0.0, -0.1, 0.1, 8)


def test_the_interval_is_scipys_paired_bca_bootstrap_of_the_mean():
    rng = np.random.default_rng(1)
    differences = rng.normal(0.3, 0.1, size=200)
    low, high = claims.interval(differences)
    assert low < differences.mean() < high
    half = 1.96 * differences.std(ddof=1) / np.sqrt(len(differences))
    assert high - low == pytest.approx(2 * half, rel=0.15)  # the normal interval, large n
    assert claims.interval(np.full(5, 0.2)) == (0.2, 0.2)


def test_lines_pair_by_run_id_and_missing_lines_say_not_run_yet(tmp_path, monkeypatch):
    monkeypatch.setattr(claims, "ROOT", tmp_path)
    for folder, values in (("a", [0.5, 0.6, 0.7]), ("b", [0.7, 0.8, 0.9, 0.1])):
        (tmp_path / folder).mkdir()
        with open(tmp_path / folder / "results.csv", "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["run_id", "status", "score", "score_all"])
            for i, value in enumerate(values):
                writer.writerow([f"run-{i:04d}", "ok", value, value / 2])
    claim = {"baseline": "a", "line": "b", "names": ["A", "B"], "expect": "better",
             "command": "make b"}  # fmt: skip
    ours, effect, verdict = claims.evidence(claim)
    assert "n = 3 paired runs" in ours and effect.startswith("+0.200")  # run-0003 has no pair
    assert verdict == "reproduced"  # the same +0.2 in every pair
    # "score": "score_all" compares the mean over all evaluations (here half the final score)
    ours, effect, verdict = claims.evidence({**claim, "score": "score_all"})
    assert "mean over all evaluations" in ours and effect.startswith("+0.100")
    ours, effect, verdict = claims.evidence({**claim, "line": "missing"})
    assert verdict == "not run yet" and ours.startswith("not run yet") and effect == "-"
    data = {"intro": "# Claims", "outro": "## Missing", "section": [
        {"title": "S", "claim": [{**claim, "line": "missing", "claim": "c", "where": "Fig 1",
                                  "form": "as run", "thesis": "t"}]}]}  # fmt: skip
    page = claims.render({**data, "missing": "Not run yet:"})
    assert page.endswith("## Missing\n\nNot run yet:\n\n- Fig 1: `make b`\n")  # the command
    # every line run: no sentence announcing a list of what is missing, no dangling colon
    data["section"][0]["claim"][0]["line"] = claim["line"]
    page = claims.render({**data, "missing": "Not run yet:"})
    assert page.endswith("## Missing\n") and "Not run yet:" not in page


def test_the_page_opens_with_a_tally_of_its_verdicts():
    calls = ["inconclusive: about 9 runs", "reproduced", "no claim to test", "reproduced"]
    assert claims.tally(calls) == (
        "**At a glance**: 4 rows: 2 reproduced, 1 inconclusive, 1 no claim to test."
    )
    page = (ROOT / "docs" / "claims.md").read_text()
    cells = [row.split(" | ")[-1] for row in page.splitlines() if row.startswith("| ")]
    heads = [cell.strip("| ").split("**")[1] for cell in cells if cell.startswith("**")]
    assert f"**At a glance**: {len(heads)} rows: " in page
    for head in set(heads):
        assert f"{heads.count(head)} {head}" in page.split("**At a glance**")[1].split("\n")[0]
