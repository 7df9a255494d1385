"""Tests of agents/a3c_tools/compare.py and agents/a3c_tools/paired.py (the pairing, the t
interval, its coverage at the runs a comparison rests on, and the verdict, shared with the claims
page).

The fast tier trains nothing: the comparisons run the real agent scripts' sweeps with the
sweep's execute_run replaced by a stand-in that writes an evaluations.csv at once, and the
committed chapter 8 runs are analysed as they are. One tiny comparison of real runs is in the
slow tier."""

import csv
import json
import re
from pathlib import Path

import numpy as np
import pytest
from a3c_tools import compare, paired, sweep
from a3c_tools import thesis_claims as claims
from conftest import ROOT, run_main
from scipy import stats

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

FF = "agents/a3c_ff.py"
LPQ = "agents/a3c_lpq.py"
COMMITTED = ("results/future_work_catch/lpq_f32", "results/future_work_catch/lpq_growth_f32")


def write_table(folder: Path, rows: list[tuple[str, str, float]]) -> Path:
    """A sweep's results.csv: (run_id, status, score) rows, score_all half the score."""
    folder.mkdir(parents=True, exist_ok=True)
    with open(folder / "results.csv", "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["run_id", "status", "score", "score_all", "seed"])
        for run_id, status, score in rows:
            writer.writerow([run_id, status, score if status == "ok" else "", score / 2, 1])
    return folder


# ------------------------------------------------------------------------------------------------
# The verdict rule and the interval (paired), on hand-made intervals and generated differences
# ------------------------------------------------------------------------------------------------
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
def test_verdicts_follow_the_interval_and_the_expected_direction(
    expect, effect, low, high, verdict
):
    assert paired.verdict(expect, effect, low, high, 8).startswith(verdict)


def test_the_margin_of_comparable_is_a_parameter():
    assert paired.verdict("comparable", 0.0, -0.08, 0.08, 8).startswith("inconclusive")
    assert paired.verdict("comparable", 0.0, -0.08, 0.08, 8, margin=0.1) == "reproduced"
    assert paired.verdict("comparable", 0.2, 0.15, 0.25, 8, margin=0.1) == "contradicted"


@pytest.mark.parametrize("confidence", [0.95, 0.975])
def test_an_inconclusive_verdict_states_the_runs_for_80_percent_power(confidence):
    # half-width 0.1 at 8 runs against an effect of 0.05: the spread s of the differences is
    # 0.1 sqrt(8) / t(7); the fewest runs n at which the two-sided paired t test at the
    # verdict's level (1 - confidence) has 80% power against a mean of 0.05 (noncentral t)
    call = paired.verdict("better", 0.05, -0.05, 0.15, 8, confidence=confidence)
    level = 1 - confidence
    found = re.fullmatch(rf"inconclusive: about (\d+) runs per line for 80% power at {level:g}",
                         call)  # fmt: skip
    assert found, call
    needed = int(found[1])
    spread = 0.1 * np.sqrt(8) / stats.t.ppf(0.5 + confidence / 2, 7)

    def power(n: int) -> float:  # P(|T| > t(1 - level / 2, n - 1)), T: nct(n - 1, 0.05 sqrt(n) / s)
        q = stats.t.ppf(1 - level / 2, n - 1)
        shift = 0.05 * np.sqrt(n) / spread
        return stats.nct.sf(q, n - 1, shift) + stats.nct.cdf(-q, n - 1, shift)

    assert power(needed) >= 0.8 > power(needed - 1)
    # about twice the n at which the interval would just exclude 0 (about 50% power)
    old = paired.runs_to_decide(0.05, 0.1, 8, confidence)
    assert 1.6 * old <= needed <= 2.5 * old
    # "comparable": the effect's distance from the band's edge, as for the claims page
    near = paired.verdict("comparable", 0.02, -0.06, 0.10, 8, confidence=confidence)
    spread = 0.08 * np.sqrt(8) / stats.t.ppf(0.5 + confidence / 2, 7)
    assert near.endswith(f"about {paired.runs_for_power(0.03, spread, level)} runs per line "
                         f"for 80% power at {level:g}")  # fmt: skip
    none = paired.verdict("better", 0.0, -0.1, 0.1, 8, confidence=confidence)
    assert none == (f"inconclusive: no number of runs per line up to {paired.MAX_POWER_RUNS} "
                    f"gives 80% power at {level:g} at this effect")  # fmt: skip


def test_the_interval_is_the_student_t_interval_of_the_paired_differences():
    rng = np.random.default_rng(1)
    for n in (3, 8, 20):
        differences = rng.normal(0.3, 0.1, size=n)
        expected = stats.t.interval(0.95, n - 1, loc=differences.mean(),
                                    scale=stats.sem(differences))  # fmt: skip
        assert paired.interval(differences) == pytest.approx(expected)
        wider = stats.t.interval(0.975, n - 1, loc=differences.mean(),
                                 scale=stats.sem(differences))  # fmt: skip
        assert paired.interval(differences, 0.975) == pytest.approx(wider)
    assert paired.interval(np.full(5, 0.2)) == (0.2, 0.2)


def no_effect_scores(rng: np.random.Generator, kind: str, shape: tuple[int, int]) -> np.ndarray:
    """One line's scores under no effect: both lines are drawn alike, so their runs are
    exchangeable. "catch": bimodal and skewed like Catch sweeps (a run learns, to about 0.9, at
    some learning rates, else stays near random play's 0.2); "lognormal": skewed; "t2":
    heavy-tailed (Student t with 2 degrees of freedom, no variance)."""
    if kind == "catch":
        learned = rng.random(shape) < 0.4
        return np.where(learned, rng.normal(0.9, 0.05, shape), rng.normal(0.22, 0.03, shape))
    if kind == "lognormal":
        return rng.lognormal(0.0, 1.0, shape)
    return rng.standard_t(2, shape)


@pytest.mark.parametrize("n", [2, 3, 5, 8, 20])
def test_with_no_true_effect_the_interval_covers_0_and_the_verdicts_are_rare(n):
    """2,000 comparisons with no effect at each n: normal differences, and lines drawn from one
    skewed, bimodal or heavy-tailed distribution. The 95% interval covers 0 in 93% of them or
    more (Monte Carlo error about 0.5%), and neither directional verdict (the "better" of
    --expect better, the "worse" of --expect worse) is given in more than 5%. Below MIN_PAIRS
    no verdict is given at all."""
    rng = np.random.default_rng(52 + n)
    draws = 2_000
    samples = {"normal": rng.normal(0.0, 0.1, (draws, n))}
    for kind in ("catch", "lognormal", "t2"):
        samples[kind] = no_effect_scores(rng, kind, (draws, n)) - no_effect_scores(
            rng, kind, (draws, n)
        )
    for kind, differences in samples.items():
        effect, low, high = paired.t_intervals(differences)
        calls = [paired.decision("better", lo, hi, n) for lo, hi in zip(low, high, strict=True)]
        if n < paired.MIN_PAIRS:
            assert set(calls) == {"no verdict"}
            if kind == "normal":  # the interval itself: exact for normal differences
                assert np.mean((low <= 0) & (high >= 0)) >= 0.93
            continue
        covers = np.mean((low <= 0) & (high >= 0))
        assert covers >= 0.93, (kind, covers)
        better, worse = calls.count("reproduced") / draws, calls.count("contradicted") / draws
        assert better <= 0.05 and worse <= 0.05, (kind, better, worse)
        assert better + worse == pytest.approx(1 - covers, abs=1e-9)


def test_a_comparison_of_two_lines_at_random_play_gives_no_verdict(tmp_path):
    ids = [f"run-{i:04d}" for i in range(4)]
    base = write_table(
        tmp_path / "base",
        [(r, "ok", s) for r, s in zip(ids, [0.208, 0.212, 0.216, 0.22], strict=True)],
    )
    other = write_table(
        tmp_path / "other",
        [(r, "ok", s) for r, s in zip(ids, [0.24, 0.244, 0.248, 0.25], strict=True)],
    )
    done = run_main(compare.main, ["--from", str(base), str(other)])
    assert done.returncode == 0, done.stderr
    assert "**+0.032 [+0.030, +0.033]**" in done.stdout  # an interval off 0, but ...
    assert "Verdict: **no verdict: both lines at random play (Catch-v0: about 0.2" in done.stdout
    assert "reproduced" not in done.stdout and "better (" not in done.stdout
    # one run that learned in either line: a verdict again
    result = paired.pair(dict(zip(ids, [0.208, 0.212, 0.216, 0.22], strict=True)),
                         dict(zip(ids, [0.24, 0.244, 0.248, 0.7], strict=True)))  # fmt: skip
    assert result.at_random_play() is None
    # an Atari game's random score, from atari_report.toml
    pong = paired.pair(dict(zip(ids, [-20.5, -20.7, -20.1, -20.9], strict=True)),
                       dict(zip(ids, [-19.9, -20.0, -19.5, -20.2], strict=True)),
                       env_id="PongNoFrameskip-v4")  # fmt: skip
    assert pong.verdict("better").startswith("no verdict: both lines at random play (Pong")


@pytest.mark.parametrize(
    ("mean", "spread", "expect", "said"),
    [
        (0.2, 0.02, "better", "better (expecting other better than base: reproduced)"),
        (-0.2, 0.02, "better", "worse (expecting other better than base: contradicted)"),
        (-0.2, 0.02, "worse", "worse (expecting other worse than base: reproduced)"),
        (0.0, 0.005, "comparable", "comparable (expecting other within +-0.05 of base: reprod"),
        (0.3, 0.02, "comparable", "better by more than 0.05 (expecting other within +-0.05"),
        (0.02, 0.3, "better", "inconclusive: "),
    ],
)
def test_the_verdict_in_words_on_generated_differences(mean, spread, expect, said):
    rng = np.random.default_rng(3)
    base = rng.uniform(0.3, 0.6, size=8)
    other = base + rng.normal(mean, spread, size=8)
    ids = [f"run-{i:04d}" for i in range(8)]
    result = paired.pair(dict(zip(ids, base, strict=True)), dict(zip(ids, other, strict=True)))
    call = result.verdict(expect)
    assert compare.answer(call, result.effect, expect, paired.MARGIN).startswith(said)


# ------------------------------------------------------------------------------------------------
# Pairing
# ------------------------------------------------------------------------------------------------
def test_runs_pair_by_run_id_leaving_out_failed_and_missing_runs(tmp_path):
    base = write_table(
        tmp_path / "base",
        [
            ("run-0000", "ok", 0.5),
            ("run-0001", "ok", 0.6),
            ("run-0002", "failed", 0.0),
            ("run-0003", "ok", 0.4),
            ("run-0004", "ok", 0.5),
        ],
    )
    other = write_table(tmp_path / "other", [("run-0001", "ok", 0.8), ("run-0000", "ok", 0.7),
                                             ("run-0002", "ok", 0.9),
                                             ("run-0004", "ok", 0.7)])  # fmt: skip
    scores = [paired.read_scores(folder / "results.csv") for folder in (base, other)]
    assert set(scores[0]) == {"run-0000", "run-0001", "run-0003", "run-0004"}  # failed: no score
    result = paired.pair(*scores)
    assert result.run_ids == ["run-0000", "run-0001", "run-0004"]  # 2 failed, 3 missing
    assert list(result.other - result.base) == pytest.approx([0.2, 0.2, 0.2])
    assert result.shown() == "+0.200 [+0.200, +0.200]"
    assert paired.pair(*scores, run_ids=["run-0000", "run-0001", "run-0003"]) is None  # 2 pairs
    done = run_main(compare.main, ["--from", str(base), str(other), "--score", "score_all"])
    assert done.returncode == 0, done.stderr
    assert "**+0.100 [+0.100, +0.100]**, the mean over 3 paired runs" in done.stdout
    assert "left out, failed or missing in a line: run-0002, run-0003" in done.stdout


def test_fewer_than_three_pairs_give_no_interval_and_no_verdict_and_exit_1(tmp_path):
    ids = ["run-0000", "run-0001", "run-0002"]
    base = write_table(tmp_path / "base", [(ids[0], "ok", 0.5), (ids[1], "ok", 0.4),
                                           (ids[2], "failed", 0)])  # fmt: skip
    other = write_table(tmp_path / "other", [(i, "ok", 0.7) for i in ids])
    done = run_main(compare.main, ["--from", str(base), str(other), "--out", str(tmp_path / "o")])
    assert done.returncode == 1, done.stdout
    assert "fewer than 3 paired runs (ok in both lines): no interval and no verdict" in done.stderr
    assert not (tmp_path / "o").exists()
    assert paired.verdict("better", 0.2, 0.1, 0.3, 2).startswith("no verdict: 2 paired runs")


def test_the_committed_lpq_growth_comparison_gives_the_claims_pages_numbers(tmp_path):
    with open(claims.CLAIMS, "rb") as f:
        data = tomllib.load(f)
    [claim] = [claim for section in data["section"] for claim in section["claim"]
               if claim.get("line") == COMMITTED[1]]  # fmt: skip
    _, effect, verdict = claims.evidence(claim)
    # as docs/claims.md shows them: one look at 15 runs, decided by its interval alone, not
    # after the page's Holm adjustment
    assert (effect, verdict) == ("-0.109 [-0.176, -0.042]", "contradicted")
    [row] = [j for j in claims.judge(data) if j.claim["id"] == claim["id"]]
    assert row.verdict.startswith("inconclusive: contradicted by its interval alone, not after")
    out = tmp_path / "cmp"
    done = run_main(compare.main, ["--from", *COMMITTED, "--out", str(out)])
    assert done.returncode == 0, done.stderr
    assert f"**{effect}**, the mean over 15 paired runs with its 95% t interval" in done.stdout
    # one comparison on its own is read at 0.05: the interval alone decides it
    assert "Verdict: **worse (expecting other better than base: contradicted)**" in done.stdout
    # the line means and standard errors of docs/future-work.md
    assert "| 15 of 15 | 0.951 +- 0.004 |" in done.stdout
    assert "| 15 of 15 | 0.843 +- 0.029 |" in done.stdout
    assert (out / "comparison.md").read_text().startswith(done.stdout.split("wrote ")[0])
    # the committed copy that docs/testing-your-idea.md shows holds the same
    committed = ROOT / "results" / "future_work_catch" / "comparison_lpq_growth"
    assert (committed / "comparison.md").read_text().split("Command:")[0] == (
        done.stdout.split("Command:")[0]
    ), "python -m a3c_tools.compare --from ... (results/future_work_catch/COMMAND.txt)"
    assert (out / "comparison.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # --from without --out prints and writes nothing
    again = run_main(compare.main, ["--from", *COMMITTED])
    assert again.stdout.split("Command:")[0] == done.stdout.split("Command:")[0]
    assert "wrote" not in again.stdout


# ------------------------------------------------------------------------------------------------
# Running: the real scripts' sweeps, their runs replaced by a stand-in
# ------------------------------------------------------------------------------------------------
@pytest.fixture
def stand_in(monkeypatch) -> list[str]:
    """The sweep's runs without training: each writes an evaluations.csv whose score follows
    from its learning rate and seed (an ELU run scores 0.1 more). Records each run's folder."""
    calls = []

    def execute_run(command: list[str], run_dir: str, stop_level=None) -> dict:
        calls.append("/".join(Path(run_dir).parts[-3::2]))  # base/run-0000
        lr = float(sweep.flag_value(command, "learning-rate") or 7e-4)  # a3c_ff.py's default
        seed = int(sweep.flag_value(command, "seed"))
        score = 0.5 + 0.1 * np.log10(lr) / 5 + 0.01 * (seed % 7) + 0.1 * ("elu" in command)
        rows = "global_step,mean_return\n" + "".join(f"{100 * i},{score}\n" for i in range(6))
        return {"returncode": 0, "interrupted": False, "wall_time_s": 0.01, "stdout_tail": "",
                "stderr_tail": "", "evaluations_csv": rows}  # fmt: skip

    monkeypatch.setattr(sweep, "execute_run", execute_run)
    return calls


def compare_ff_elu(out: Path, *extra: str):
    argv = [FF, FF, "--other-flags", "--activation elu", "--runs", "3", "--steps", "500",
            "--cpus", "2", "--out", str(out), *extra]  # fmt: skip
    return run_main(compare.main, argv)


def table(folder: Path) -> dict[str, dict]:
    with open(folder / "results.csv", newline="") as f:
        return {row["run_id"]: row for row in csv.DictReader(f)}


def test_both_lines_run_at_the_same_learning_rates_and_seeds_in_turns(stand_in, tmp_path):
    out = tmp_path / "cmp"
    done = compare_ff_elu(out)
    assert done.returncode == 0, done.stderr
    # rounds of 2 (2 CPUs, 1 worker per run), the lines in turn, so a stopped comparison pairs
    assert stand_in == ["base/run-0000", "base/run-0001", "other/run-0000", "other/run-0001",
                        "base/run-0002", "other/run-0002"]  # fmt: skip
    base, other = table(out / "base"), table(out / "other")
    for run_id in base:
        assert base[run_id]["learning-rate"] == other[run_id]["learning-rate"]
        assert base[run_id]["seed"] == other[run_id]["seed"]
        assert "--activation elu" in other[run_id]["flags"]
        assert "--eval-interval 25" in other[run_id]["flags"]  # 500 steps / 20
    assert len({row["learning-rate"] for row in base.values()}) == 3
    assert float(other["run-0000"]["score"]) == pytest.approx(
        float(base["run-0000"]["score"]) + 0.1
    )
    assert "**+0.100 [+0.100, +0.100]**, the mean over 3 paired runs" in done.stdout
    assert "Verdict: **better (expecting other better than base: reproduced)**" in done.stdout
    assert json.loads((out / "base" / "sweep.json").read_text())["total_timesteps"] == 500
    assert (out / "comparison.md").is_file() and (out / "comparison.png").is_file()


def test_a_finished_comparison_runs_nothing_and_an_interrupted_one_the_rest(stand_in, tmp_path):
    out = tmp_path / "cmp"
    first = compare_ff_elu(out)
    assert first.returncode == 0 and len(stand_in) == 6
    stand_in.clear()
    again = compare_ff_elu(out)  # finished: the result again, nothing run
    assert again.returncode == 0 and stand_in == []
    result = first.stdout[first.stdout.index("# a3c_ff.py --activation elu") :]
    assert again.stdout == result  # the result alone: no sweep was started
    # interrupted before other's run-0002 ended: that run alone runs
    rows = table(out / "other")
    del rows["run-0002"]
    with open(out / "other" / "results.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, list(next(iter(rows.values()))))
        writer.writeheader()
        writer.writerows(rows.values())
    resumed = compare_ff_elu(out)
    assert resumed.returncode == 0 and stand_in == ["other/run-0002"]
    # a larger --runs extends both lines
    stand_in.clear()
    assert compare_ff_elu(out, "--runs", "4").returncode == 0
    assert stand_in == ["base/run-0003", "other/run-0003"]


# ------------------------------------------------------------------------------------------------
# Bad input: one line, exit 2, nothing created
# ------------------------------------------------------------------------------------------------
NOT_AGENT = "agents/a3c_tools/sweep.py"


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        ([FF, "agents/a3c_nope.py"], "OTHER agents/a3c_nope.py: no such file"),
        ([FF, NOT_AGENT], f"OTHER {NOT_AGENT} is not an agent script"),
        ([FF, FF], "the same script with the same flags"),
        ([FF, LPQ, "--base-flags", "--prototypes-per-action 4"],
         "--base-flags: a3c_ff.py has no flag --prototypes-per-action"),
        ([FF, FF, "--other-flags", "--activation tanh"], "--other-flags: a3c_ff.py refuses them: "
         "invalid choice 'tanh' for argument '--activation'"),
        ([FF, FF, "--other-flags", "--t-max 0"], "a3c_ff.py refuses them: --t-max must be >= 1"),
        ([FF, LPQ, "--other-flags", "--seed 3"], "--other-flags sets --seed"),
        ([FF, LPQ, "--other-flags", "--learning-rate 1e-3"], "sampled in --lr-range"),
        ([FF, LPQ, "--steps", "300"], "--steps 300 is too small to evaluate"),
        ([FF, LPQ, "--eval-interval", "10"], "--eval-interval 10 is closer than one update"),
        ([FF, LPQ, "--fast", "--steps", "6000"], "use --steps >= 6400"),
        ([FF, LPQ, "--steps", "1000", "--eval-interval", "400"], "use --steps >= 2000"),
        ([FF, LPQ, "--margin", "0"], "argument --margin: must be > 0"),
        ([FF, LPQ, "--expect", "maybe"], "invalid choice: 'maybe'"),
        ([FF, LPQ, "--runs", "1"], "--runs must be >= 3 (got 1)"),
        ([FF, LPQ, "--runs", "2"], "--runs must be >= 3 (got 2)"),
        ([FF], "name two agent scripts"),
        ([FF, LPQ, "--from", *COMMITTED], "--from analyses sweeps already run: BASE OTHER"),
        (["--from", COMMITTED[0], "results/sweep_catch/a3c_ff"], "the two sweeps do not pair"),
        ([FF, LPQ, "--device", "cuda"], "--device needs --backend batched"),
        ([FF, "agents/future_work/a3c_lws_online.py", "--backend", "batched"],
         "not a3c_lws_online.py; use --backend local"),
        ([FF, LPQ, "--fast", "--backend", "batched"], "cannot batch --num-workers 2"),
    ],
)  # fmt: skip
def test_bad_input_is_one_line_exit_2_and_creates_nothing(stand_in, tmp_path, argv, message):
    out = tmp_path / "cmp"
    done = run_main(compare.main, [*argv, "--out", str(out)])
    assert done.returncode == 2, done.stdout + done.stderr
    assert message in done.stderr and len(done.stderr.strip().splitlines()) == 1, done.stderr
    assert not out.exists() and stand_in == []


def test_an_out_holding_other_sweeps_is_refused_before_either_runs(stand_in, tmp_path):
    out = tmp_path / "cmp"
    assert compare_ff_elu(out).returncode == 0
    stand_in.clear()
    done = compare_ff_elu(out, "--seed", "2")
    assert done.returncode == 2 and stand_in == []
    assert f"{out / 'base'} holds a sweep with another configuration (seed: 1 there" in done.stderr


def test_the_flag_sets_reach_their_own_line_only(stand_in, tmp_path):
    out = tmp_path / "cmp"
    argv = [
        FF,
        LPQ,
        "--base-flags",
        "--t-max 10",
        "--other-flags",
        "--prototypes-per-action 4",
        "--runs",
        "3",
        "--fast",
        "--steps",
        "6400",
        "--lr-range",
        "default",
        "--out",
        str(out),
    ]
    done = run_main(compare.main, argv)
    assert done.returncode == 0, done.stderr
    configs = [json.loads((out / side / "sweep.json").read_text()) for side in ("base", "other")]
    assert [c["script"] for c in configs] == ["a3c_ff.py", "a3c_lpq.py"]
    fast = ["--envs-per-worker", "16", "--num-workers", "2", "--eval-interval", "320"]
    assert configs[0]["fixed_flags"] == ["--t-max", "10", *fast]
    assert configs[1]["fixed_flags"] == ["--prototypes-per-action", "4", *fast]
    assert configs[0]["samples"] == configs[1]["samples"] == []  # the scripts' default rate
    assert "samples: none, the scripts' default learning rate" in done.stdout


def test_an_interrupted_sweep_stops_the_comparison_with_130(stand_in, tmp_path, monkeypatch):
    monkeypatch.setattr(sweep, "sweep", lambda args, fixed: 130)  # Ctrl-C during base's sweep
    out = tmp_path / "cmp"
    done = compare_ff_elu(out)
    assert done.returncode == 130 and "the same command resumes" in done.stdout
    assert not (out / "comparison.md").exists()


def tiny_ff_elu(out: Path, steps: str, interval: str, *extra: str) -> list[str]:
    """A3C FF against itself with ELU, 3 runs a line, 2 episodes an evaluation."""
    return [FF, FF, "--other-flags", "--activation elu", "--runs", "3", "--steps", steps,
            "--eval-interval", interval, "--eval-episodes", "2", *extra,
            "--out", str(out)]  # fmt: skip


def run_three_pairs(argv: list[str], out: Path):
    """The comparison run; it succeeds and both lines hold runs 0-2."""
    done = run_main(compare.main, argv)
    assert done.returncode == 0, done.stdout + done.stderr
    base, other = table(out / "base"), table(out / "other")
    assert sorted(base) == sorted(other) == ["run-0000", "run-0001", "run-0002"]
    return done, base, other


@pytest.mark.slow
def test_a_tiny_comparison_end_to_end(tmp_path):
    """Two configurations of a3c_ff.py, 3 runs each of 2,000 steps, 1 worker: both lines run
    at the same learning rates and seeds, the result is written, and a second start runs
    nothing."""
    out = tmp_path / "cmp"
    argv = tiny_ff_elu(out, "2000", "400", "--cpus", "2")
    done, base, other = run_three_pairs(argv, out)
    for run_id, row in base.items():
        assert row["status"] == other[run_id]["status"] == "ok", (row, other[run_id])
        assert row["learning-rate"] == other[run_id]["learning-rate"]
        assert row["seed"] == other[run_id]["seed"]
        assert int(row["evaluations"]) >= 6 and int(row["final_step"]) >= 2000
    assert "the mean over 3 paired runs" in done.stdout and "Verdict: **" in done.stdout
    assert (out / "comparison.png").stat().st_size > 10_000
    again = run_main(compare.main, argv)
    assert again.returncode == 0 and again.stdout.startswith("# a3c_ff.py --activation elu")


@pytest.mark.parametrize(
    "tool", ["atari_report", "compare", "thesis_claims", "thesis_figures", "atari_figures", "sweep"]
)
def test_the_tools_help_prints_single_percent_signs(tool):
    import importlib

    module = importlib.import_module(f"a3c_tools.{tool}")
    done = run_main(module.main, ["--help"])
    assert done.returncode == 0 and "usage" in done.stdout
    assert "%%" not in done.stdout and "%(" not in done.stdout


def test_the_runs_that_would_decide_a_row_stop_at_max_runs():
    """Beyond MAX_RUNS per line the interval estimate is None, never MAX_RUNS + 1; beyond
    MAX_POWER_RUNS the verdict says no number of runs gives 80% power, never a larger one."""
    for distance in np.geomspace(1e-3, 1.0, 400):
        needed = paired.runs_to_decide(float(distance), 0.1, 8)
        assert needed is None or 8 < needed <= paired.MAX_RUNS, (distance, needed)
    for effect in np.geomspace(1e-4, 0.1, 60):
        words = paired.verdict("better", float(effect), effect - 0.1, effect + 0.1, 8)
        found = re.search(r"about (\d+) runs", words)
        assert found is None or int(found[1]) <= paired.MAX_POWER_RUNS, words
        assert found is not None or "no number of runs per line up to 5000" in words, words


def test_from_a_folder_whose_sweep_json_is_not_an_object_exits_2_in_one_line(tmp_path):
    folders = [tmp_path / "base", tmp_path / "other"]
    for folder in folders:
        folder.mkdir()
        (folder / "results.csv").write_text("run_id,status,score,flags,error\n")
        (folder / "sweep.json").write_text('{"seed": 1, "samples": []}')
    (folders[1] / "sweep.json").write_text("[1, 2]")
    result = run_main(compare.main, ["--from", *map(str, folders)])
    assert result.returncode == 2
    assert (
        len(result.stderr.splitlines()) == 1 and "is not a sweep's configuration" in result.stderr
    )


@pytest.mark.parametrize(
    ("side", "name", "text", "said"),
    [
        ("base", "results.csv", "run_id,status,score\nrun-0000,ok,0.5\nrun-0001,ok,abc\n",
         "results.csv: run 'run-0001': its score is 'abc', not a number"),  # once a traceback
        ("other", "results.csv", "run_id,status,score,learning-rate\nrun-0000,ok,0.5,fast\n",
         "results.csv: run 'run-0000': its learning-rate is 'fast', not a number"),
        ("other", "results.csv", "run_id,score\nrun-0000,0.5\n",
         "results.csv is not a sweep's table: no status column"),
        ("base", "sweep.json", "[" * 100_000,
         "sweep.json is not a sweep's configuration (JSON nested too deep to read)"),
        ("other", "sweep.json", '{"seed": 1, "samples": [], "fixed_flags": []}',
         "sweep.json is not a sweep's configuration (it has no 'script')"),
    ],
    ids=["a score", "a learning rate", "no status", "nested 100,000 deep", "no script"],
)  # fmt: skip
def test_from_a_folder_it_cannot_read_exits_2_in_one_line(tmp_path, side, name, text, said):
    """--from reads two folders someone may hand on: a results.csv or sweep.json it cannot
    use is one line naming what is wrong, exit 2, nothing written."""
    config = {"script": "a3c_ff.py", "samples": [], "fixed_flags": [], "total_timesteps": 500,
              "seed": 1, "score": "mean of the final 5 evaluations"}  # fmt: skip
    folders = {}
    for line, shift in (("base", 0.0), ("other", 0.1)):
        rows = [(f"run-{i:04d}", "ok", 0.5 + 0.01 * i + shift) for i in range(3)]
        folders[line] = write_table(tmp_path / line, rows)
        (folders[line] / "sweep.json").write_text(json.dumps(config))
    (folders[side] / name).write_text(text)
    out = tmp_path / "out"
    argv = ["--from", str(folders["base"]), str(folders["other"]), "--out", str(out)]
    result = run_main(compare.main, argv)
    assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
    assert result.stderr.startswith(f"error: {folders[side] / name}"), result.stderr
    assert said in result.stderr, result.stderr
    assert not out.exists()


def test_a_batched_comparison_runs_each_line_as_one_program(tmp_path):
    """--backend batched: each line's 3 runs are one batched program (their closing lines say
    so), paired by learning rate and seed as on the process backend, and the result is written."""
    out = tmp_path / "cmp"
    done, base, other = run_three_pairs(tiny_ff_elu(out, "150", "30", "--backend", "batched"), out)
    for run_id, row in base.items():
        assert row["status"] == other[run_id]["status"] == "ok"
        assert (row["learning-rate"], row["seed"]) == (
            other[run_id]["learning-rate"], other[run_id]["seed"])  # fmt: skip
        for side in ("base", "other"):
            log = (out / side / "runs" / run_id / "stdout.log").read_text()
            assert "batched with 3 runs" in log
    assert "the mean over 3 paired runs" in done.stdout
