"""Tests of the confirmatory study read as a referee would (a3c_tools.study_reading and the
statistics it adds to a3c_tools.paired): the equivalence rule's power against simulation, the
sensitivity numbers against their definitions, and every number the claims page states about
the study recomputed here from the committed results.csv files with scipy and numpy alone."""

import csv
import dataclasses
import math
import re

import numpy as np
import pytest
from a3c_tools import confirmatory, paired, read_toml, study_reading, thesis_claims
from conftest import ROOT, run_main
from scipy import stats

PLAN = ROOT / "results" / "confirmatory" / "plan.toml"
NEXT = ROOT / "results" / "confirmatory_1m" / "plan.toml"
LEVEL = 0.05 / 7  # the first study's Holm level


def load(path):
    return read_toml(path)


def claim(study, claim_id):
    return next(c for c in study["claim"] if c["id"] == claim_id)


def scores(folder, runs):
    """run_id -> (learning rate, score) of a committed line's runs 0..runs-1 (ok only)."""
    with open(ROOT / folder / "results.csv", newline="") as f:
        rows = {r["run_id"]: r for r in csv.DictReader(f) if r["status"] == "ok"}
    ids = [f"run-{i:04d}" for i in range(runs)]
    return {i: (float(rows[i].get("learning-rate") or 0), float(rows[i]["score"]))
            for i in ids if i in rows}  # fmt: skip


def differences(test, runs):
    """(learning rates, baseline, lines' mean, line - baseline) of a Catch test, by hand."""
    base = scores(test["baseline"], runs)
    lines = [scores(f, runs) for f in test.get("lines", [test.get("line")])]
    ids = [i for i in base if all(i in line for line in lines)]
    b = np.array([base[i][1] for i in ids])
    x = np.array([[line[i][1] for i in ids] for line in lines])
    rates = np.array([base[i][0] for i in ids])
    return rates, b, x, x.mean(axis=0) - b


def nct_power(effect, spread, n, alpha):
    """The paired t test's power from scipy's noncentral t (fine at these n)."""
    q = stats.t.ppf(1 - alpha / 2, n - 1)
    shift = effect * math.sqrt(n) / spread
    return stats.nct.sf(q, n - 1, shift) + stats.nct.cdf(-q, n - 1, shift)


@pytest.mark.parametrize("effect, spread, runs", [(0.0, 0.0764, 33), (0.03, 0.06, 20)])
def test_equivalence_power_is_the_chance_the_interval_lies_inside_the_band(effect, spread, runs):
    rng = np.random.default_rng(0)
    d = rng.normal(effect, spread, (100_000, runs))
    mean, half = (
        d.mean(axis=1),
        stats.t.ppf(1 - LEVEL / 2, runs - 1) * d.std(axis=1, ddof=1) / math.sqrt(runs),
    )
    simulated = ((mean - half > -paired.MARGIN) & (mean + half < paired.MARGIN)).mean()
    assert paired.equivalence_power(effect, spread, runs, LEVEL) == pytest.approx(
        simulated, abs=0.006
    )


def test_the_plans_80_percent_for_comparable_claims_is_about_60_under_the_verdicts_rule():
    study = load(PLAN)
    for claim_id, expected in (("P6", 0.60), ("P7", 0.61)):
        c = claim(study, claim_id)
        planned = confirmatory.plan_claim(c, 7, study["study"])
        assert planned.power == pytest.approx(0.80, abs=0.005)  # the plan's two-sided figure
        rule = paired.equivalence_power(0.0, planned.spread, c["runs"], LEVEL)
        assert rule == pytest.approx(expected, abs=0.005)
        runs = paired.equivalence_runs(0.0, planned.spread, LEVEL)
        assert paired.equivalence_power(0.0, planned.spread, runs, LEVEL) >= 0.8
        assert paired.equivalence_power(0.0, planned.spread, runs - 1, LEVEL) < 0.8


def test_smallest_effect_and_equivalence_reach_invert_the_power():
    effect = paired.smallest_effect(0.0624, 15, LEVEL)
    assert nct_power(effect, 0.0624, 15, LEVEL) == pytest.approx(0.8, abs=1e-3)
    reach = paired.equivalence_reach(0.0711, 64, LEVEL)
    assert 0 < reach < paired.MARGIN
    assert paired.equivalence_power(reach, 0.0711, 64, LEVEL) == pytest.approx(0.8, abs=1e-4)
    assert paired.equivalence_reach(0.0969, 33, LEVEL) is None  # even a true 0 has less


def test_a_pilots_spread_interval_is_the_chi_square_one():
    low, high = paired.spread_interval(1.0476, 3)  # P3's pilot: 3 seeds, 2 degrees of freedom
    assert (round(low, 2), round(high, 1)) == (0.55, 6.6)
    assert high == pytest.approx(1.0476 * math.sqrt(2 / stats.chi2.ppf(0.025, 2)))


def test_the_next_study_is_sized_for_the_upper_limit_of_the_first_studys_spread():
    done = run_main(confirmatory.main, [str(NEXT), "--check"])
    assert done.returncode == 0, done.stdout
    study = load(NEXT)
    first = load(PLAN)
    assert study["study"]["spread_upper"] == 0.8
    for c in study["claim"]:
        d = confirmatory.differences(c["spread_from"])
        upper = d.std(ddof=1) * math.sqrt((d.size - 1) / stats.chi2.ppf(0.2, d.size - 1))
        planned = confirmatory.plan_claim(c, len(study["claim"]), study["study"])
        assert planned.spread == pytest.approx(upper)
        assert planned.level == pytest.approx(0.05 / 3)
        assert nct_power(abs(c["effect"]), upper, c["runs"], 0.05 / 3) >= 0.8
        assert nct_power(abs(c["effect"]), upper, c["runs"] - 1, 0.05 / 3) < 0.8
        # its pilots are the first study's own lines of the same configuration
        tests = [f["test"] for f in first["claim"]]
        assert any(c["spread_from"]["baseline"] == t["baseline"] for t in tests)
    items = {item["id"]: item for item in study["item"]}
    assert {item["total_timesteps"] for item in items.values()} == {1_000_000}  # the thesis's
    assert all("--eval-interval" not in item["flags"] for item in items.values())  # 50,000
    assert {item["seed"] for item in items.values()} == {8200}


def test_an_inconclusive_comparable_claim_outside_the_band_reads_not_comparable():
    c = {"expect": "comparable"}
    outside = confirmatory.Outcome("P", 33, 0.086, 0.052, 0.121, 0.038, 0.063, "inconclusive")
    text = study_reading.answer_of(c, outside, 1e-5, ("A3C FF", "GLPQ"))
    assert text.startswith("not comparable: GLPQ scores above A3C FF") and "exploratory" in text
    below = dataclasses.replace(outside, effect=-0.086, low=-0.121, high=-0.052)
    assert "GLPQ scores below A3C FF" in study_reading.answer_of(c, below, 1e-5, ("A3C FF", "GLPQ"))
    straddles = dataclasses.replace(outside, low=0.04)
    assert study_reading.answer_of(c, straddles, 1e-5) == "inconclusive"
    assert study_reading.answer_of({"expect": "better"}, outside, 1e-5) == "inconclusive"


def table_rows(section, first):
    """The Markdown rows of the table whose header starts with `first`, in a section."""
    lines = section.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(first))
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("| "):
            break
        rows.append([cell.strip() for cell in line.strip("|").split(" | ")])
    return rows


def test_the_page_states_each_verdicts_budget_power_and_reading_as_computed_here():
    text = (ROOT / "docs" / "claims.md").read_text()
    study = load(PLAN)
    confirm = text.split("## The confirmatory study")[1].split("\n## ")[0]
    verdicts = {r[0]: r for r in table_rows(confirm, "| id | primary claim")}
    catch = "250,000 steps a run on Catch, a quarter of the thesis's 1M"
    breakout = "2,000,000 steps a run on Breakout, a thirtieth of the thesis's 60M"
    for c in study["claim"]:
        budget = breakout if "atari" in c["test"] else catch
        assert f"** at {budget}" in verdicts[c["id"]][-1]  # every verdict at its budget
    # P7: the data, not only the rule's word; its p of d = 0 from scipy's paired t test
    _, b, x, d = differences(claim(study, "P7")["test"], 33)
    p_zero = stats.ttest_rel(x[0], b).pvalue
    assert f"p of d = 0: {p_zero:.1g}" in verdicts["P7"][-1]
    assert verdicts["P7"][-1].startswith("**inconclusive** at")
    assert (
        "the data: not comparable: GLPQ hot (as run) scores above A3C FF (as run)"
        in (verdicts["P7"][-1])
    )
    # the two comparable claims' p-values test opposite things, and say so
    assert "p of d = +0.05 (small: inside the band)" in verdicts["P6"][5]
    assert "p of d = +0.05 (small: outside the band)" in verdicts["P7"][5]
    assert "p of d = 0: " in verdicts["P1"][5]
    # power, planned and achieved: the sensitivity numbers from scipy's noncentral t
    power = {r[0]: r for r in table_rows(confirm, "| id | p tests")}
    _, _, _, d1 = differences(claim(study, "P1")["test"], 15)
    s1 = d1.std(ddof=1)
    assert power["P1"][5].startswith(f"{nct_power(0.05, s1, 15, LEVEL):.0%} at {s1:.3f}")
    assert power["P1"][5] == "51% at 0.062 (24)"
    p5 = confirmatory.plan_claim(claim(study, "P5"), 7, study["study"])
    pilot = confirmatory.differences(claim(study, "P5")["spread_from"]).mean()
    assert power["P5"][4] == f"{nct_power(pilot, p5.spread, 8, LEVEL):.0%}" == "44%"
    assert power["P6"][3] == "80%; 60%" and power["P7"][3] == "80%; 61%"
    assert power["P7"][4] == "0.4%"  # at its pilot's +0.049, at the band's edge
    assert power["P3"][5] == "1% at 8.56 (444)" and power["P3"][2].startswith(
        "3, 1.05 [0.55, 6.58]"
    )
    # what each verdict rests on: P3 not testable at its own spread, P6's floor
    rests = confirm.split("### What each verdict rests on")[1]
    p3 = next(line for line in rests.splitlines() if line.startswith("- **P3**"))
    assert "would have needed 444 runs per line, past its cap of 10" in p3
    assert "not testable" in p3 and "different hosts" in p3
    p6 = next(line for line in rests.splitlines() if line.startswith("- **P6**"))
    rates, b, x, d = differences(claim(study, "P6")["test"], 64)
    floor = (b <= 0.3) & (x.max(axis=0) <= 0.3)
    learning = d[~floor]
    half = stats.t.ppf(0.975, learning.size - 1) * learning.std(ddof=1) / math.sqrt(learning.size)
    assert f"{floor.sum()} of its 64 pairs have both lines at random play" in p6
    assert (f"on the {learning.size} pairs where either line learns: {learning.mean():+.3f} "
            f"[{learning.mean() - half:+.3f}, {learning.mean() + half:+.3f}]") in p6  # fmt: skip
    top = np.argsort(rates, kind="stable")[-16:]
    assert f"{d[top].mean():+.3f} ({rates[top].min():.0e}-{rates[top].max():.0e}, n = 16)" in p6
    for claim_id in ("P1", "P5", "P6", "P7"):  # their pilots' baseline learned in bf16
        line = next(line for line in rests.splitlines() if line.startswith(f"- **{claim_id}**"))
        assert "bf16-learn" in line
    # one answer per conclusion, at its budget; the exploratory rows beside it, labelled
    answer = text.split("## The answer")[1].split("\n## ")[0]
    rows = table_rows(answer, "| the thesis concludes")
    assert [r[1] for r in rows if "competitive with the softmax" in r[0]] == [
        "**partly reproduced**"
    ]
    for r in rows:
        assert re.fullmatch(r"\*\*[a-z ]+\*\*( \((exploratory only|the study's look waits)\))?",
                            r[1])  # fmt: skip
        assert "steps a run on" in r[2]
    # the study's tally says at what budget
    tally = text.split("**The confirmatory study at a glance**: ")[1].split("\n")[0]
    assert f"6 at {catch}" in tally and f"1 at {breakout}" in tally


def test_the_next_study_is_on_the_page_as_planned():
    text = (ROOT / "docs" / "claims.md").read_text()
    section = text.split("## The next study: the thesis's budget")[1].split("\n## ")[0]
    assert "**Status**: planned, not yet run." in section
    rows = table_rows(section, "| id | primary claim")
    assert [r[0] for r in rows] == ["Q1", "Q2", "Q3"]
    assert all(r[-1] == "**planned, not yet run**" for r in rows)
    assert thesis_claims.CONFIRMATORY_NEXT == NEXT


def test_the_readings_sensitivity_is_at_the_studys_own_spread():
    study = load(PLAN)
    found = dict(zip([c["id"] for c in study["claim"]], confirmatory.outcomes(study), strict=True))
    for claim_id, runs in (("P1", 15), ("P5", 8)):
        c = claim(study, claim_id)
        r = study_reading.read(c, found[claim_id], study)
        _, _, _, d = differences(c["test"], runs)
        assert r.study_spread == pytest.approx(d.std(ddof=1))
        expected = nct_power(abs(c["effect"]), d.std(ddof=1), runs, LEVEL)
        assert r.study_power == pytest.approx(expected, abs=1e-3)
        assert r.testable and r.verdict == "inconclusive" == r.answer
