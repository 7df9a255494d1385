"""Tests of agents/a3c_tools/compare.py and agents/a3c_tools/paired.py (the pairing, the BCa
interval and the verdict, shared with the claims page).

The fast tier trains nothing: the comparisons run the real agent scripts' sweeps with the
sweep's execute_run replaced by a stand-in that writes an evaluations.csv at once, and the
committed chapter 8 runs are analysed as they are. One tiny comparison of real runs is in the
slow tier."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from a3c_tools import compare, paired, sweep
from a3c_tools import thesis_claims as claims
from conftest import ROOT, run_main

FF = "agents/a3c_ff.py"
LPQ = "agents/a3c_lpq.py"
COMMITTED = ("results/future_work_catch/lpq", "results/future_work_catch/lpq_growth")


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


def test_an_inconclusive_verdict_states_the_runs_that_would_decide_it():
    # half-width 0.1 against an effect of 0.05: the interval must shrink 2x, so 4x the runs
    assert paired.verdict("better", 0.05, -0.05, 0.15, 8) == (
        "inconclusive: about 32 runs per line would decide it"
    )
    assert "would not decide it" in paired.verdict("better", 0.0, -0.1, 0.1, 8)


def test_the_interval_is_scipys_paired_bca_bootstrap_of_the_mean():
    rng = np.random.default_rng(1)
    differences = rng.normal(0.3, 0.1, size=200)
    low, high = paired.interval(differences)
    assert low < differences.mean() < high
    half = 1.96 * differences.std(ddof=1) / np.sqrt(len(differences))
    assert high - low == pytest.approx(2 * half, rel=0.15)  # the normal interval, large n
    assert paired.interval(np.full(5, 0.2)) == (0.2, 0.2)


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
        ],
    )
    other = write_table(tmp_path / "other", [("run-0001", "ok", 0.8), ("run-0000", "ok", 0.7),
                                             ("run-0002", "ok", 0.9)])  # fmt: skip
    scores = [paired.read_scores(folder / "results.csv") for folder in (base, other)]
    assert set(scores[0]) == {"run-0000", "run-0001", "run-0003"}  # the failed run is no score
    result = paired.pair(*scores)
    assert result.run_ids == ["run-0000", "run-0001"]  # 2 failed in base, 3 missing in other
    assert list(result.other - result.base) == pytest.approx([0.2, 0.2])
    assert result.shown() == "+0.200 [+0.200, +0.200]"
    assert paired.pair({"run-0000": 0.1}, {"run-0000": 0.2}) is None  # one pair: no interval
    done = run_main(compare.main, ["--from", str(base), str(other), "--score", "score_all"])
    assert done.returncode == 0, done.stderr
    assert "**+0.100 [+0.100, +0.100]**, the mean over 2 paired runs" in done.stdout
    assert "left out, failed or missing in a line: run-0002, run-0003" in done.stdout


def test_fewer_than_two_pairs_give_no_interval_and_exit_1(tmp_path):
    base = write_table(tmp_path / "base", [("run-0000", "ok", 0.5), ("run-0001", "failed", 0)])
    other = write_table(tmp_path / "other", [("run-0000", "ok", 0.7), ("run-0001", "ok", 0.7)])
    done = run_main(compare.main, ["--from", str(base), str(other), "--out", str(tmp_path / "o")])
    assert done.returncode == 1 and "fewer than 2 paired runs" in done.stderr
    assert not (tmp_path / "o").exists()


def test_the_committed_lpq_growth_comparison_gives_the_claims_pages_numbers(tmp_path):
    with open(claims.CLAIMS, "rb") as f:
        data = claims.tomllib.load(f)
    [claim] = [claim for section in data["section"] for claim in section["claim"]
               if claim.get("line") == COMMITTED[1]]  # fmt: skip
    _, effect, verdict = claims.evidence(claim)
    assert (effect, verdict) == (
        "+0.063 [-0.073, +0.238]",
        "inconclusive: about 91 runs per line would decide it",
    )  # as docs/claims.md shows them
    out = tmp_path / "cmp"
    done = run_main(compare.main, ["--from", *COMMITTED, "--out", str(out)])
    assert done.returncode == 0, done.stderr
    assert f"**{effect}**, the mean over 15 paired runs" in done.stdout
    assert f"Verdict: **{verdict} (expecting other better than base)**" in done.stdout
    # the line means and standard errors of docs/future-work.md
    assert "| 15 of 15 | 0.755 +- 0.064 |" in done.stdout
    assert "| 15 of 15 | 0.819 +- 0.037 |" in done.stdout
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
        ([FF], "name two agent scripts"),
        ([FF, LPQ, "--from", *COMMITTED], "--from analyses sweeps already run: BASE OTHER"),
        (["--from", COMMITTED[0], "results/sweep_catch/a3c_ff"], "the two sweeps do not pair"),
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
        "2",
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


@pytest.mark.slow
def test_a_tiny_comparison_end_to_end(tmp_path):
    """Two configurations of a3c_ff.py, 2 runs each of 2,000 steps, 1 worker: both lines run
    at the same learning rates and seeds, the result is written, and a second start runs
    nothing."""
    out = tmp_path / "cmp"
    argv = [FF, FF, "--other-flags", "--activation elu", "--runs", "2", "--steps", "2000",
            "--eval-episodes", "2", "--cpus", "2", "--out", str(out)]  # fmt: skip
    done = run_main(compare.main, argv)
    assert done.returncode == 0, done.stdout + done.stderr
    base, other = table(out / "base"), table(out / "other")
    assert sorted(base) == sorted(other) == ["run-0000", "run-0001"]
    for run_id, row in base.items():
        assert row["status"] == other[run_id]["status"] == "ok", (row, other[run_id])
        assert row["learning-rate"] == other[run_id]["learning-rate"]
        assert row["seed"] == other[run_id]["seed"]
        assert int(row["evaluations"]) >= 6 and int(row["final_step"]) >= 2000
    assert "the mean over 2 paired runs" in done.stdout and "Verdict: **" in done.stdout
    assert (out / "comparison.png").stat().st_size > 10_000
    again = run_main(compare.main, argv)
    assert again.returncode == 0 and again.stdout.startswith("# a3c_ff.py --activation elu")
