"""Tests of a3c_tools.confirmatory: the pre-registered plan (results/confirmatory/plan.toml) holds
the runs per line that the committed runs' spread gives for 80% power at the Holm level, its
run seeds are new, and its items are the campaign's (load and pair up)."""

import numpy as np
import pytest
from a3c_tools import campaign, confirmatory, paired
from conftest import ROOT, run_main

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

PLAN = ROOT / "results" / "confirmatory" / "plan.toml"


def plan() -> dict:
    return tomllib.loads(PLAN.read_text())


def test_the_committed_plan_passes_its_check():
    done = run_main(confirmatory.main, [str(PLAN), "--check"])
    assert done.returncode == 0, done.stdout
    assert "holds what the committed runs give, and its seeds are new" in done.stdout


def test_each_claims_runs_are_the_fewest_for_80_percent_power_at_the_holm_level():
    data = plan()
    claims = data["claim"]
    assert [c["id"] for c in claims] == [f"P{i}" for i in range(1, 8)]
    for claim in claims:
        d = confirmatory.differences(claim["spread_from"])
        level = 0.05 / len(claims)  # Holm's first step over the family
        gap = abs(claim["effect"]) if claim["expect"] != "comparable" else paired.MARGIN
        cap = claim.get("max_runs", data["study"]["max_runs"])
        n = claim["runs"]
        assert claim["level"] == pytest.approx(level, abs=1e-5)
        got = paired.power(gap, d.std(ddof=1), n, level)
        assert claim["power"] == pytest.approx(got, abs=0.005)
        if n < cap:  # the fewest: one run fewer falls short
            assert got >= 0.8 > paired.power(gap, d.std(ddof=1), n - 1, level)
        for item in (i for i in data["item"] if i["id"] in claim["items"]):
            assert item.get("runs", item.get("seeds")) >= n


def test_the_claims_left_out_state_the_runs_and_hours_80_percent_power_would_need():
    # P8 and P9 (LPQ, GLPQ below A3C FF on Breakout) left the family before any run: at their
    # committed spread the 10 seeds we can afford give about 1% power
    data = plan()
    left = data["not_testable"]
    assert [e["id"] for e in left] == ["P8", "P9"]
    assert not {e["id"] for e in left} & {c["id"] for c in data["claim"]}
    assert not any(i["id"].startswith("a2") for i in data["item"])  # their Atari item is gone
    level = 0.05 / (len(data["claim"]) + len(left))  # as if they had stayed in the family
    for entry in left:
        d = confirmatory.differences(entry["spread_from"])
        spread, effect, n = d.std(ddof=1), abs(entry["effect"]), entry["runs"]
        assert entry["level"] == pytest.approx(level, abs=1e-5)
        assert (
            paired.power(effect, spread, n, level)
            >= 0.8
            > paired.power(effect, spread, n - 1, level)
        )
        assert entry["power"] == pytest.approx(
            paired.power(effect, spread, entry["max_runs"], level), abs=0.005
        )
        assert entry["power"] < 0.05 and n > 30 * entry["max_runs"]  # far out of reach
        rates = []  # CPU-seconds per step of each line, from its committed runs
        for folder in entry["rate_from"]:
            rows = [r for r in campaign.read_rows(ROOT / folder) if r["status"] == "ok"]
            rates.append(np.mean([float(r["wall_time_s"]) / float(r["final_step"]) for r in rows]))
        hours = n * entry["steps"] * entry["num_workers"] * sum(rates) / 3600
        assert entry["cpu_hours"] == round(hours)
    shown = confirmatory.table(data)
    assert "| P8 | 3 |" in shown and f"| {left[1]['runs']} | 0.01 at 10 | " in shown


def test_the_composite_claim_pairs_the_mean_of_its_lines_run_by_run():
    spec = plan()["claim"][0]["spread_from"]
    base = paired.read_scores(ROOT / spec["baseline"] / "results.csv")
    lines = [paired.read_scores(ROOT / f / "results.csv") for f in spec["lines"]]
    ids = [f"run-{i:04d}" for i in range(8)]
    expected = [np.mean([line[i] for line in lines]) - base[i] for i in ids]
    assert confirmatory.differences(spec) == pytest.approx(expected)


def test_the_check_fails_on_a_changed_number_or_a_used_seed(tmp_path):
    text = PLAN.read_text()
    changed = tmp_path / "plan.toml"
    changed.write_text(text.replace("runs = 15\npower", "runs = 12\npower", 1))
    done = run_main(confirmatory.main, [str(changed), "--check"])
    assert done.returncode == 1 and "P1: the plan says runs, power, level (12" in done.stdout
    changed.write_text(text.replace("seed = 7600", "seed = 1"))  # atari_figures' and sweeps'
    done = run_main(confirmatory.main, [str(changed), "--check"])
    assert done.returncode == 1 and "run seeds already used by committed runs: [1, " in done.stdout
    # the study's own runs (seeds 7500, ...: in its output folders) are not "used before"
    own = confirmatory.output_folders(tomllib.loads(text))
    assert 1 in confirmatory.committed_seeds(own=own)
    assert 7500 not in confirmatory.committed_seeds(own=own)
    old = 'test = { baseline = "results/confirmatory/catch/lpq_low_lr"'
    changed.write_text(text.replace(old, old.replace("lpq_low_lr", "nowhere")))
    done = run_main(confirmatory.main, [str(changed), "--check"])
    assert done.returncode == 1 and "P4: its test reads ['results/confirmatory/catch/nowhere']" \
        in done.stdout  # fmt: skip
    changed.write_text(text.replace("runs = 383", "runs = 10", 1))  # P8 made to look testable
    done = run_main(confirmatory.main, [str(changed), "--check"])
    assert done.returncode == 1 and "P8 (not testable): the plan says runs, power, level, " \
        "CPU-hours (10, " in done.stdout  # fmt: skip
    changed.write_text(text.replace("runs = 8\nseed = 7500", "runs = 20\nseed = 7500", 1))
    done = run_main(confirmatory.main, [str(changed), "--check"])
    assert done.returncode == 1 and "item c3-glpq-searing: 20 runs per line, its claims need 8" \
        in done.stdout  # fmt: skip


def test_the_plans_items_are_the_campaigns_with_new_seeds_and_paired_lines():
    items = {item.id: item for item in campaign.load_plan(PLAN)}
    seeds = {}
    for item in items.values():
        for sweep in item.sweeps:
            command = sweep.command
            seeds[sweep.out] = int(command[command.index("--seed") + 1])
            assert command[command.index("--total-timesteps") + 1] in ("250000", "2000000")
            if item.kind == "sweep":  # float32, as the thesis ran
                assert command[-2:] == ["--precision", "fp32"] or "fp32" in command
    assert set(seeds.values()) == {7500, 7600, 7700, 7800}
    assert all(seed % 1000 != 1 for seed in seeds.values())  # every committed seed is 1 + 1000 i


def test_the_compute_table_counts_each_items_runs_at_its_committed_rate():
    data = plan()
    item = next(i for i in data["item"] if i["id"] == "c3-glpq-searing")
    rows = [r for r in campaign.read_rows(ROOT / item["rate_from"][0]) if r["status"] == "ok"]
    per_step = np.mean([float(r["wall_time_s"]) / float(r["final_step"]) for r in rows])
    assert confirmatory.cpu_hours(item) == pytest.approx(8 * 250_000 * per_step / 3600)
    table = confirmatory.compute(data)
    assert "| c3-glpq-searing | 8 x 1 | 250,000 |" in table and "| **all** |" in table


def write_line(folder, values, statuses=None):
    folder.mkdir(parents=True, exist_ok=True)
    lines = ["run_id,status,score"] + [
        f"run-{i:04d},{(statuses or ['ok'] * len(values))[i]},{v}" for i, v in enumerate(values)
    ]
    (folder / "results.csv").write_text("\n".join(lines) + "\n")


def test_the_one_look_waits_for_every_run_then_judges_at_the_holm_level(tmp_path, monkeypatch):
    from a3c_tools import thesis_claims

    monkeypatch.setattr(confirmatory, "ROOT", tmp_path)
    base = np.linspace(0.3, 0.7, 6)
    write_line(tmp_path / "results" / "ff", base)
    write_line(
        tmp_path / "results" / "up", base + [0.20, 0.22, 0.19, 0.21, 0.20, 0.18]
    )  # clearly better
    write_line(
        tmp_path / "results" / "same", (base + [0.01, -0.01, 0.0, 0.02, -0.02, 0.0])[:5]
    )  # 5 of 6
    plan = {
        "study": {"alpha": 0.05},
        "claim": [
            {"id": "A", "expect": "better", "runs": 6,
             "test": {"baseline": "results/ff", "line": "results/up"}},
            {"id": "B", "expect": "comparable", "runs": 6,
             "test": {"baseline": "results/ff", "line": "results/same"}},
        ],
    }  # fmt: skip
    assert confirmatory.outcomes(plan) is None  # one look: not before every run is in
    write_line(tmp_path / "results" / "same", base + [0.01, -0.01, 0.0, 0.02, -0.02, 0.0])
    a, b = confirmatory.outcomes(plan)
    pa = paired.p_value(np.array([0.20, 0.22, 0.19, 0.21, 0.20, 0.18]))
    pb = paired.margin_p_value(np.array([0.01, -0.01, 0.0, 0.02, -0.02, 0.0]))
    assert (a.p, b.p) == pytest.approx((pa, pb))
    assert [a.adjusted, b.adjusted] == pytest.approx(paired.holm([pa, pb]))
    assert (a.verdict, b.verdict) == ("reproduced", "reproduced") and a.pairs == 6
    # the wrong direction is contradicted; a failed run counts as in, its pair left out
    plan["claim"][0]["expect"] = "worse"
    write_line(tmp_path / "results" / "up", base + 0.2, ["ok"] * 5 + ["failed"])
    a, _ = confirmatory.outcomes(plan)
    assert a.verdict == "contradicted" and a.pairs == 5
    # a "comparable" line decidedly outside the band is contradicted, on either side
    for sign in (1, -1):
        write_line(
            tmp_path / "results" / "same",
            base + sign * np.array([0.3, 0.32, 0.29, 0.31, 0.3, 0.28]),
        )
        _, b = confirmatory.outcomes(plan)
        assert b.verdict == "contradicted" and b.adjusted < 0.05
    write_line(tmp_path / "results" / "same", base + [0.01, -0.01, 0.0, 0.02, -0.02, 0.0])
    # the claims page shows each claim's result once the look is taken
    path = tmp_path / "plan.toml"
    path.write_text(
        '[study]\nalpha = 0.05\npower = 0.8\nmax_runs = 100\n[[claim]]\nid = "A"\n'
        'claim = "c"\nexperiment = "e"\nexpect = "better"\neffect = 0.1\n'
        'effect_basis = "b"\nruns = 6\npower = 0.9\nlevel = 0.05\nitems = ["i"]\n'
        'spread_from = { baseline = "results/ff", line = "results/same", runs = 6 }\n'
        'test = { baseline = "results/ff", line = "results/same" }\n'
        '[[item]]\nid = "i"\ntotal_timesteps = 250000\n'
    )
    [_, _, row] = thesis_claims.confirmatory(path)
    budget = "250,000 steps a run on Catch, a quarter of the thesis's 1M"
    assert "(n = 6), p of d = 0: " in row and row.endswith(f"| **inconclusive** at {budget} |")
    assert thesis_claims.confirmatory_status(path).startswith("done: every run is in")
    # ... and its verdicts follow it: the answer's column, the study's tally, the forest plot
    assert thesis_claims.study_verdicts(path) == {"A": "inconclusive"}
    assert thesis_claims.study_tally({}, path) == (
        f"**The confirmatory study at a glance**: 1 primary claim: 1 inconclusive; 1 at {budget}."
    )
    conclusion = {"conclusion": [{"claim": "c", "rows": [], "primary": "A"},
                                 {"claim": "d", "rows": [], "primary": "- (not run)"}]}  # fmt: skip
    table = thesis_claims.conclusions(conclusion, [], path)
    # one answer per conclusion: the study's where it tests it, at its budget
    assert [row.split(" | ")[1:4] for row in table[2:]] == [
        ["**inconclusive**", budget, "A (**inconclusive**)"],
        ["**untested** (exploratory only)", "-", "- (not run)"],
    ]
    d = np.array([0.01, -0.01, 0.0, 0.02, -0.02, 0.0])
    [point] = thesis_claims.study_points({"study_labels": {"A": "same > ff"}}, path)
    assert point.label == "A: same > ff" and point.section == thesis_claims.STUDY_SECTION
    assert (point.effect, point.low, point.high) == tuple(
        round(x, 3) for x in (d.mean(), *paired.interval(d))
    )
    assert (point.verdict, point.colour) == ("inconclusive", thesis_claims.COLOURS["inconclusive"])
    write_line(tmp_path / "results" / "same", base[:3])  # 6 + 3 of the 12 runs in, and no look
    assert thesis_claims.confirmatory(path)[2].endswith("| - | **under way: 9 of 12 runs in** |")
    assert thesis_claims.study_verdicts(path) == {} and thesis_claims.study_tally({}, path) is None
    assert thesis_claims.study_points({}, path) == []  # no score read before the look
    assert thesis_claims.conclusions(conclusion, [], path)[2].split(" | ")[1:4] == [
        "**untested** (the study's look waits)",
        "-",
        "A",
    ]
    assert thesis_claims.confirmatory_status(path).endswith("under way, 9 of its 12 runs in")
    path.write_text(path.read_text() + '[[claim]]\nid = "B"\nclaim = "c"\nexperiment = "e"\n'
                    'expect = "better"\neffect = 0.1\neffect_basis = "b"\nruns = 3\n'
                    'power = 0.9\nlevel = 0.05\n'
                    'test = { baseline = "results/ff", line = "results/same" }\n')  # fmt: skip
    assert thesis_claims.confirmatory(path)[3].endswith(
        "| - | **all 6 runs in; waits for the one look** |"  # B's runs in, A's not: no look
    )
    for folder in ("ff", "same"):
        (tmp_path / "results" / folder / "results.csv").unlink()
    assert thesis_claims.confirmatory(path)[2].endswith("| - | **planned, not yet run** |")
    assert thesis_claims.confirmatory_status(path) == "planned, not yet run"


def test_the_runs_in_are_counted_from_run_ids_alone_each_line_once(tmp_path, monkeypatch):
    """While the study runs the page counts its runs without reading a score (a table with no
    score column counts the same), runs past a claim's own are not its, an Atari run counts
    once it reached the steps, and a line two claims read counts once in the heading."""
    from a3c_tools import thesis_claims

    monkeypatch.setattr(confirmatory, "ROOT", tmp_path)
    (tmp_path / "results" / "ff").mkdir(parents=True)
    (tmp_path / "results" / "ff" / "results.csv").write_text(
        "run_id,status\n" + "".join(f"run-{i:04d},ok\n" for i in range(7))
    )
    write_line(tmp_path / "results" / "lpq", [0.5] * 2)
    assert confirmatory.runs_in({"baseline": "results/ff", "line": "results/lpq"}, 5) == {
        ("results/ff",): 5, ("results/lpq",): 2
    }  # fmt: skip
    composite = {"baseline": "results/ff", "lines": ["results/lpq", "results/none"]}
    assert confirmatory.runs_in(composite, 8) == {
        ("results/ff",): 7, ("results/lpq",): 2, ("results/none",): 0
    }  # fmt: skip
    figure = tmp_path / "results" / "atari" / "fig6.9" / "Breakout"
    (figure / "ff").mkdir(parents=True)
    (figure / "ff" / "results.csv").write_text(
        "run_id,status,final_step,seed\nrun-0000,ok,2000080,7800\nrun-0001,ok,1000000,8800\n"
        "run-0002,ok,2000080,9800\nrun-0003,ok,2000080,1\n"
    )  # run 1 stopped short; seed 1 is not the study's
    atari = {"atari": "results/atari/fig6.9", "game": "Breakout", "baseline": "ff", "line": "lws",
             "seed": 7800, "steps": 2000000}  # fmt: skip
    key = ("results/atari/fig6.9", "Breakout")
    assert confirmatory.runs_in(atari, 10) == {(*key, "ff"): 2, (*key, "lws"): 0}
    assert confirmatory.runs_in(atari, 2) == {(*key, "ff"): 1, (*key, "lws"): 0}
    path = tmp_path / "plan.toml"
    claim = ('[[claim]]\nid = "{}"\nclaim = "c"\nexperiment = "e"\nexpect = "better"\n'
             'effect = 0.1\neffect_basis = "b"\nruns = {}\npower = 0.9\nlevel = 0.05\n'
             'test = {{ baseline = "results/ff", line = "results/{}" }}\n')  # fmt: skip
    path.write_text(
        "[study]\nalpha = 0.05\n" + claim.format("A", 4, "lpq") + claim.format("B", 8, "x")
    )
    # ff: 8 needed (B's), 7 in; lpq: 4 needed, 2 in; x: 8 needed, none in
    assert thesis_claims.confirmatory_status(path).endswith("under way, 9 of its 20 runs in")


def test_the_one_look_at_an_atari_claim_pairs_the_studys_seeds_at_its_steps(tmp_path, monkeypatch):
    """An Atari claim's runs are in when each of its seeds (seed + 1000 i, i < runs) is in both
    lines' tables, failed or at its steps; the look reads each run's score from its line's own
    results.csv (PLAN.md, amendment 5: no run folder needed), the runs of those seeds at the
    steps, paired by seed, a failed run's pair left out."""
    monkeypatch.setattr(confirmatory, "ROOT", tmp_path)
    runs = {"ff": {7800: (10.0, 2000080), 8800: (20.0, 2000080), 9800: (30.0, 2000080),
                   1: (99.0, 2000080)},
            "lws": {7800: (7.0, 2000080), 8800: (16.0, 2000080), 9800: (25.0, 1000000),
                    1: (0.0, 2000080)}}  # fmt: skip

    def write_lines(failed: int | None = None) -> None:
        for line, scores in runs.items():
            folder = tmp_path / "results" / "fig" / "Breakout" / line
            folder.mkdir(parents=True, exist_ok=True)
            rows = [f"run-{i:04d},{'failed' if seed == failed else 'ok'},{score},{step},{seed}\n"
                    for i, (seed, (score, step)) in enumerate(scores.items())]  # fmt: skip
            (folder / "results.csv").write_text("run_id,status,score,final_step,seed\n"
                                                + "".join(rows))  # fmt: skip

    write_lines()  # lws seed 9800 stopped short; seed 1 is not the study's
    spec = {"atari": "results/fig", "game": "Breakout", "baseline": "ff", "line": "lws",
            "seed": 7800, "steps": 2000000}  # fmt: skip
    assert confirmatory.differences({**spec, "runs": 3}).tolist() == [-3.0, -4.0]
    assert confirmatory.runs_in(spec, 3) == {("results/fig", "Breakout", "ff"): 3,
                                             ("results/fig", "Breakout", "lws"): 2}  # fmt: skip
    assert not confirmatory.complete(spec, 3) and confirmatory.complete(spec, 2)
    plan = {"study": {"alpha": 0.05},
            "claim": [{"id": "P3", "expect": "worse", "runs": 3, "test": spec}]}  # fmt: skip
    assert confirmatory.outcomes(plan) is None  # one of its runs is short of the steps
    write_lines(failed=9800)  # it failed: in, and its pair left out
    assert confirmatory.complete(spec, 3)
    [p3] = confirmatory.outcomes(plan)
    assert (p3.pairs, p3.effect) == (2, pytest.approx(-3.5))
    runs["lws"][9800] = (25.0, 2000080)  # failed after its last evaluation: still left out
    write_lines(failed=9800)
    [p3] = confirmatory.outcomes(plan)
    assert (p3.pairs, p3.effect) == (2, pytest.approx(-3.5))
    write_lines()  # it finished instead
    [p3] = confirmatory.outcomes(plan)
    assert (p3.pairs, p3.effect) == (3, pytest.approx(-4.0))
    assert p3.p == pytest.approx(paired.p_value(np.array([-3.0, -4.0, -5.0])))


def test_a_line_an_atari_figure_shares_is_read_from_the_figure_that_runs_it(tmp_path, monkeypatch):
    """Figure 7.8's A3C FF is Figure 6.9's runs (atari_figures' same_as): a claim on Figure
    7.8 reads its FF scores from fig6.9/GAME/ff, its own lines from fig7.8/GAME/LINE."""
    monkeypatch.setattr(confirmatory, "ROOT", tmp_path)
    for folder, score in (("fig6.9/Breakout/ff", 40.0), ("fig7.8/Breakout/lpq_fig78", 30.0)):
        (tmp_path / "results" / "x" / folder).mkdir(parents=True)
        (tmp_path / "results" / "x" / folder / "results.csv").write_text(
            f"run_id,status,score,final_step,seed\nrun-0000,ok,{score},2000080,1\n"
        )
    spec = {"atari": "results/x/fig7.8", "game": "Breakout", "baseline": "ff",
            "line": "lpq_fig78"}  # fmt: skip
    assert confirmatory.atari_line_folder(spec, "ff") == tmp_path / "results/x/fig6.9/Breakout/ff"
    assert confirmatory.differences(spec).tolist() == [-10.0]


def test_a_bad_plan_is_one_line_and_exit_2(tmp_path):
    missing = run_main(confirmatory.main, [str(tmp_path / "none.toml")])
    assert missing.returncode == 2 and len(missing.stderr.strip().splitlines()) == 1
    short = tmp_path / "short.toml"
    short.write_text('[study]\nalpha = 0.05\n[[claim]]\nid = "A"\n')
    done = run_main(confirmatory.main, [str(short), "--check"])
    assert done.returncode == 2 and done.stderr.strip() == f"{short}: no 'spread_from'"
    assert "Traceback" not in done.stderr
    outside = tmp_path / "outside.toml"  # a folder outside results/ is refused before it is read
    outside.write_text(
        PLAN.read_text().replace('"results/thesis_figures_catch/fig6.7/relu"', '"../../etc"', 1)
    )
    refused = run_main(confirmatory.main, [str(outside)])
    assert refused.returncode == 2
    assert refused.stderr.strip() == f"{outside}: '../../etc' is not a folder under results/"


@pytest.mark.parametrize(
    "text", ["a = " + "[" * 100_000, "a = " + "{ b = " * 100_000], ids=["arrays", "tables"]
)
def test_a_plan_nested_too_deep_is_one_line_and_exit_2(tmp_path, text):
    deep = tmp_path / "deep.toml"
    deep.write_text(text)
    for options in ([], ["--check"]):
        done = run_main(confirmatory.main, [str(deep), *options])
        assert (done.returncode, done.stdout) == (2, "")
        assert done.stderr == f"{deep}: TOML nested too deep to read\n"


def test_the_campaigns_progress_estimates_the_studys_cpu_hours_from_its_rate_from():
    """PROGRESS.md's "CPU-hours left" for a study's plan (no cpu_hours_per_run) is the compute
    table's, item by item, until a line has runs of its own."""
    items = campaign.load_plan(PLAN)
    table, _ = campaign.progress(items)
    planned = {item["id"]: item for item in plan()["item"]}
    for item in items:
        if all(not campaign.read_rows(sweep.out) for sweep in item.sweeps):
            row = next(line for line in table.splitlines() if line.startswith(f"| {item.id}:"))
            left = float(row.split(" | ")[3])
            wanted = confirmatory.cpu_hours(planned[item.id])
            assert left == pytest.approx(wanted, abs=0.051), item.id


def test_the_studys_own_runs_do_not_count_as_used_seeds(tmp_path):
    """The seed check reads every committed results.csv but the study's own output folders:
    its runs, once committed, use its seeds; any other run with one of them is a clash."""
    for folder, seed in (("own/ff", 7800), ("other", 7600)):
        (tmp_path / folder).mkdir(parents=True)
        (tmp_path / folder / "results.csv").write_text(f"run_id,seed\nrun-0000,{seed}\n")
    seeds = confirmatory.committed_seeds(tmp_path, own=(tmp_path / "own",))
    assert seeds == {7600}
    assert confirmatory.committed_seeds(tmp_path) == {7600, 7800}
    own = confirmatory.output_folders(plan())
    assert ROOT / "results" / "confirmatory" / "atari" in own
    assert ROOT / "results" / "confirmatory" / "catch" / "ff_as_run" in own
