"""Tests of a3c_tools.campaign (a fixed plan of sweeps, run in order over sessions) and of the
committed plan, results/campaign/plan.toml.

The runs go through the real sweep.py with a stand-in agent script that writes its evaluations
at once; the committed plan is checked against the committed lines it extends.
"""

import csv
import json
import os
import shlex
import signal
import textwrap
import threading
import time
from pathlib import Path

import a3c_tools
import pytest
from a3c_runtime import checkpoints
from a3c_tools import campaign, figure_sweeps, sweep
from conftest import ROOT, load_script, run_main, shared_for, tiny_args

PLAN = ROOT / "results" / "campaign" / "plan.toml"

FAKE_AGENT = textwrap.dedent(
    """
    import argparse, json, os

    parser = argparse.ArgumentParser()
    for flag in ("--learning-rate", "--eval-interval", "--num-workers", "--total-timesteps",
                 "--seed", "--run-dir", "--resume"):
        parser.add_argument(flag)
    args = parser.parse_args()
    run_dir = os.path.dirname(args.resume) if args.resume else args.run_dir
    saved = json.load(open(args.resume)) if args.resume else vars(args)
    here = os.path.dirname(os.path.abspath(__file__))
    with open(os.path.join(here, "starts.log"), "a") as f:
        f.write(os.path.basename(run_dir) + "\\n")
    json.dump(saved, open(os.path.join(run_dir, "checkpoint.pt"), "w"))
    score = float(saved["learning_rate"]) * 100 + int(saved["seed"]) % 7 / 10
    with open(os.path.join(run_dir, "evaluations.csv"), "w") as f:
        f.write("global_step,wall_time_s,mean_return,std_return,episodes\\n")
        for step in range(0, int(saved["total_timesteps"]) + 1, int(saved["eval_interval"])):
            f.write(f"{step},0.1,{score},0.0,5\\n")
    """
)


@pytest.fixture(autouse=True)
def tmp_path_is_part_of_the_clone(tmp_path, monkeypatch):
    """The tests' plans name folders and stand-in agents in tmp_path: the plan's checks take
    those as the clone's results/ and agent scripts, and hold every other path to the real ones
    (test_a_bad_plan_exits_2_with_one_line_and_runs_nothing tests the real checks)."""
    for name in ("results_folder", "agent_script"):
        real = getattr(a3c_tools, name)

        def check(value, real=real):
            return Path(value) if Path(value).resolve().is_relative_to(tmp_path) else real(value)

        monkeypatch.setattr(campaign, name, check)


@pytest.fixture
def line(tmp_path):
    """A committed line of 2 runs, made by sweep.py with the stand-in agent (its seed is not
    sweep.py's default, so that an extension that lost the line's own seed shows)."""
    agents = tmp_path / "agents"
    agents.mkdir()
    (agents / "a3c_ff.py").write_text(FAKE_AGENT)
    out = tmp_path / "line"
    args = [str(agents / "a3c_ff.py"), "--out", str(out), "--runs", "2", "--seed", "7",
            "--total-timesteps", "100", "--sample", "learning-rate=loguniform:1e-5:1e-2",
            "--", "--eval-interval", "50"]  # fmt: skip
    assert run_main(sweep.main, args).returncode == 0
    (agents / "starts.log").unlink()
    return out


def write_plan(tmp_path: Path, items: str) -> Path:
    plan = tmp_path / "plan" / "plan.toml"
    plan.parent.mkdir(exist_ok=True)
    plan.write_text(textwrap.dedent(items))
    return plan


def extend_plan(tmp_path: Path, line: Path, runs: int) -> Path:
    """A plan of one item, "a1", that extends the fixture's line (2 runs) to `runs`."""
    agent = line.parent / "agents" / "a3c_ff.py"
    return write_plan(
        tmp_path,
        f"""
        [[item]]
        id = "a1"
        title = "the line to {runs} runs"
        kind = "extend"
        runs = {runs}
        lines = [{{ script = "{agent}", out = "{line}", first_look = 2 }}]
        """,
    )


def starts(line: Path) -> list[str]:
    log = line.parent / "agents" / "starts.log"
    return log.read_text().split() if log.exists() else []


def rows(folder: Path) -> list[dict]:
    with (folder / "results.csv").open(newline="") as f:
        return list(csv.DictReader(f))


def test_extend_keeps_the_first_runs_adds_the_rest_and_resumes(line, tmp_path, monkeypatch):
    before = rows(line)
    plan = extend_plan(tmp_path, line, 4)
    # pinned to one core (taskset): the sweep runs one run at a time, and its row says 1 core
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: {0}, raising=False)
    result = run_main(campaign.main, [str(plan)])
    assert result.returncode == 0, result.stderr
    assert sorted(starts(line)) == ["run-0002", "run-0003"]  # the first look's runs are kept
    after = rows(line)
    assert after[:2] == before and len(after) == 4
    # run i draws what a 4-run sweep of the same configuration draws
    fresh = sweep.plan_runs(json.loads((line / "sweep.json").read_text()), 4)
    assert [r["learning-rate"] for r in after] == [r.sampled["learning-rate"] for r in fresh]
    assert [r["seed"] for r in after] == ["7", "1007", "2007", "3007"]  # the line's own seeds
    progress = (plan.parent / "PROGRESS.md").read_text()
    assert "| a1: the line to 4 runs | 2 of 2 |" in progress
    assert "**2 of 2**" in progress
    with (plan.parent / "SWEEPS.tsv").open(newline="") as f:
        (logged,) = list(csv.DictReader(f, delimiter="\t"))
    assert (logged["item"], logged["out"]) == ("a1", str(line))
    assert (logged["runs_before"], logged["runs_after"]) == ("2", "4")
    assert logged["cpu"] and logged["cores"] == "1" and float(logged["wall_s"]) >= 0
    # the same command again: nothing left to run
    (line.parent / "agents" / "starts.log").unlink()
    assert run_main(campaign.main, [str(plan)]).returncode == 0
    assert starts(line) == []


def test_progress_counts_a_shared_line_once_and_estimates_what_is_left(line, tmp_path):
    agent = line.parent / "agents" / "a3c_ff.py"
    entry = f'{{ script = "{agent}", out = "{line}", first_look = 2 }}'
    plan = write_plan(
        tmp_path,
        f"""
        [[item]]
        id = "a1"
        title = "to 3"
        kind = "extend"
        runs = 3
        lines = [{entry}]

        [[item]]
        id = "a2"
        title = "to 3 again"
        kind = "extend"
        runs = 3
        lines = [{entry}]
        """,
    )
    result = run_main(campaign.main, [str(plan), "--status"])
    assert result.returncode == 0, result.stderr
    assert starts(line) == []  # --status runs nothing
    walls = [float(r["wall_time_s"]) / 3600 for r in rows(line)]
    left = f"{sum(walls) / len(walls):.1f}"
    assert f"| a1: to 3 | 0 of 1 | 0.0 | {left} |" in result.stdout
    assert "| a2: to 3 again | 0 of 0 | 0.0 | 0.0 |" in result.stdout
    assert "**0 of 1**" in result.stdout


def test_progress_counts_a_begun_runs_steps_from_its_checkpoint(line, tmp_path):
    plan = extend_plan(tmp_path, line, 4)
    run_dir = line / "runs" / "run-0002"  # begun (elsewhere, say), half its 100 steps done
    run_dir.mkdir(parents=True)
    module = load_script("a3c_ff")
    args = tiny_args(module)
    shared = shared_for(module, args)
    shared.steps[0] = 50
    checkpoints.save_checkpoint(run_dir / "checkpoint.pt", shared, args, 1.0, "a3c_ff.py")
    committed = rows(line)
    for row in committed:  # each finished run: one CPU-hour (one worker, an hour)
        row["wall_time_s"] = "3600"
    with (line / "results.csv").open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(committed[0]))
        writer.writeheader()
        writer.writerows(committed)
    result = run_main(campaign.main, [str(plan), "--status"])
    assert result.returncode == 0, result.stderr
    # left: run 3 whole and the half of run 2 not done yet
    assert "| a1: the line to 4 runs | 0 of 2 | 0.0 | 1.5 |" in result.stdout
    assert "| 1 (50% of their steps) |\n" in result.stdout


def repeat_plan(line: Path, tmp_path: Path, item: str, title: str, more: str = "") -> Path:
    """A plan of one repeat item of line's runs into tmp_path/again (`more`: its extra keys)."""
    agent = line.parent / "agents" / "a3c_ff.py"
    return write_plan(
        tmp_path,
        f"""
        [[item]]
        id = "{item}"
        title = "{title}"
        kind = "repeat"
        script = "{agent}"
        source = "{line}"
        out = "{tmp_path / "again"}"
        {more}
        """,
    )


def test_repeat_runs_run_0_again_and_compares_its_score(line, tmp_path):
    plan = repeat_plan(line, tmp_path, "a0", "run 0 again")
    assert run_main(campaign.main, [str(plan)]).returncode == 0
    assert rows(tmp_path / "again")[0]["score"] == rows(line)[0]["score"]
    assert "run 0 again" in (plan.parent / "PROGRESS.md").read_text()
    assert ": identical" in (plan.parent / "PROGRESS.md").read_text()


def test_repeat_of_a_chosen_run_says_whether_it_agrees_within_the_stated_margin(line, tmp_path):
    plan = repeat_plan(line, tmp_path, "a0b", "run 1 again", "run = 1\n        agree_within = 0.05")
    assert run_main(campaign.main, [str(plan)]).returncode == 0
    assert rows(tmp_path / "again")[1]["score"] == rows(line)[1]["score"]
    progress = (plan.parent / "PROGRESS.md").read_text()
    assert f"- a0b: run 1 again {float(rows(line)[1]['score']):.4f}" in progress
    assert ": identical (agrees: within 0.05)" in progress
    # a version that scores 0.06 higher does not learn the same by the stated criterion
    table = tmp_path / "again" / "results.csv"
    again = rows(tmp_path / "again")
    again[1]["score"] = str(float(again[1]["score"]) + 0.06)
    with table.open("w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(again[0]))
        writer.writeheader()
        writer.writerows(again)
    assert "differs by +0.0600 (DISAGREES: within 0.05)" in campaign.repeat_report(
        campaign.load_plan(plan), plan
    )


def test_a_sweep_item_makes_new_paired_lines_from_the_plans_own_configuration(line, tmp_path):
    agent = line.parent / "agents" / "a3c_ff.py"
    new = [tmp_path / "new_a", tmp_path / "new_b"]
    entries = ", ".join(f'{{ script = "{agent}", out = "{out}" }}' for out in new)
    plan = write_plan(
        tmp_path,
        f"""
        [[item]]
        id = "c1"
        title = "two new lines"
        kind = "sweep"
        runs = 2
        seed = 7500
        total_timesteps = 100
        samples = ["learning-rate=loguniform:1e-5:1e-2"]
        flags = ["--eval-interval", "50"]
        lines = [{entries}]
        """,
    )
    assert run_main(campaign.main, [str(plan)]).returncode == 0
    a, b = rows(new[0]), rows(new[1])
    assert [r["seed"] for r in a] == [r["seed"] for r in b] == ["7500", "8500"]  # new seeds
    assert [r["learning-rate"] for r in a] == [r["learning-rate"] for r in b]  # they pair up
    assert {r["seed"] for r in rows(line)}.isdisjoint(r["seed"] for r in a)
    bad = write_plan(
        tmp_path,
        """
        [[item]]
        id = "c1"
        title = "t"
        kind = "sweep"
        runs = 2
        seed = 7500
        total_timesteps = 100
        lines = [{ script = "agents/no_such_agent.py", out = "x" }]
        """,
    )
    done = run_main(campaign.main, [str(bad)])
    assert done.returncode == 2 and "no agent script agents/no_such_agent.py" in done.stderr


def pong_item(out: Path, lines: list[str]) -> str:
    """A plan's item "b": Figure 6.10's `lines` on Pong, 3 seeds x 3M steps, into `out`."""
    return textwrap.dedent(
        f"""
        [[item]]
        id = "b"
        title = "Pong"
        kind = "atari"
        figure = "fig6.10"
        game = "Pong"
        lines = {json.dumps(lines)}
        seeds = 3
        steps = 3000000
        num_workers = 2
        out = "{out}"
        """
    )


def test_an_atari_item_draws_its_figure_after_each_sweep(tmp_path, monkeypatch):
    """The figure's results.csv, which the claims page's Atari rows read, follows the runs."""
    plan = write_plan(
        tmp_path,
        f"""
        {pong_item(tmp_path / "atari", ["vf1.0", "vf0.5"])}
        """,
    )
    ran = []
    monkeypatch.setattr(campaign, "execute", lambda command: (ran.append(command[:2]), (0, ""))[1])
    assert run_main(campaign.main, [str(plan)]).returncode == 1  # the stand-in ran no run
    draw = ["-m", "a3c_tools.atari_figures"]
    assert ran == [["-m", "a3c_tools.sweep"], draw, ["-m", "a3c_tools.sweep"], draw]
    # every run done before this start (or brought from another machine): drawn once
    for line in ("vf1.0", "vf0.5"):
        folder = tmp_path / "atari" / "fig6.10" / "Pong" / line
        folder.mkdir(parents=True)
        (folder / "results.csv").write_text("run_id,status,wall_time_s,flags\n" + "".join(
            f"run-{i:04d},ok,1,--num-workers 2\n" for i in range(3)))  # fmt: skip
    ran.clear()
    assert run_main(campaign.main, [str(plan)]).returncode == 0
    assert ran == [draw]
    printed = run_main(campaign.main, [str(plan), "--dry-run"]).stdout.splitlines()
    assert printed[-1] == f"python -m a3c_tools.atari_figures fig6.10 --out {tmp_path / 'atari'} "\
        "--plot-only"  # fmt: skip


@pytest.mark.parametrize(
    "body, message",
    [
        ('kind = "other"\nid = "x"\ntitle = "t"', "kind 'other'; valid: extend, repeat, atari"),
        ('kind = "extend"\ntitle = "t"', "has no id"),
        ('kind = "extend"\nid = "x"\ntitle = "t"\nruns = 3\n'
         'lines = [{ script = "agents/a3c_ff.py", out = "TMP/nowhere" }]',
         "nowhere has no sweep.json"),
        ('kind = "extend"\nid = "x"\ntitle = "t"\nruns = 3\n'
         'lines = [{ script = "/bin/sh", out = "LINE" }]',
         "no agent script /bin/sh; valid: agents/a3c_*.py, agents/future_work/a3c_*.py"),
        ('kind = "extend"\nid = "x"\ntitle = "t"\nruns = 3\n'
         'lines = [{ script = "agents/../tests/conftest.py", out = "LINE" }]',
         "no agent script agents/../tests/conftest.py"),
        ('kind = "extend"\nid = "x"\ntitle = "t"\nruns = 3\n'
         'lines = [{ script = "agents/a3c_ff.py", out = "results/../../outside" }]',
         "'results/../../outside' is not a folder under results/"),
        ('kind = "repeat"\nid = "x"\ntitle = "t"\nscript = "agents/a3c_ff.py"\n'
         'source = "LINE"\nout = "/tmp"', "'/tmp' is not a folder under results/"),
        ('kind = "extend"\nid = "x"\ntitle = "t"\nruns = 3\n'
         'lines = [{ script = "agents/a3c_lws.py", out = "LINE" }]', "a sweep of a3c_ff.py, not"),
        ('kind = "atari"\nid = "x"\ntitle = "t"\nfigure = "fig6.10"\ngame = "Pong"\n'
         'lines = ["vf2"]\nseeds = 3\nsteps = 10\nnum_workers = 1\nout = "TMP/o"',
         "has no line vf2"),
        ('kind = "atari"\nid = "x"\ntitle = "t"\nfigure = "fig6.10"\ngame = "../../x"\n'
         'lines = ["vf1.0"]\nseeds = 3\nsteps = 10\nnum_workers = 1\nout = "TMP/o"',
         "fig6.10 has no game '../../x'; valid: Pong"),
    ],
)  # fmt: skip
def test_a_bad_plan_exits_2_with_one_line_and_runs_nothing(line, tmp_path, body, message):
    body = body.replace("LINE", str(line)).replace("TMP", str(tmp_path))
    plan = write_plan(tmp_path, "[[item]]\n" + body + "\n")
    result = run_main(campaign.main, [str(plan)])
    assert result.returncode == 2
    assert len(result.stderr.splitlines()) == 1 and message in result.stderr, result.stderr
    assert starts(line) == [] and not (plan.parent / "PROGRESS.md").exists()


def test_the_committed_plan_extends_each_line_with_its_own_configuration():
    items = campaign.load_plan(PLAN)
    extended = [s for item in items if item.kind == "extend" for s in item.sweeps]
    assert len(extended) == 20  # a0-a7's 14, and f1/f1b's float32 reruns of chapter 8's 6
    for planned in extended:
        source = planned.out if planned.first_look else Path(str(planned.out).replace("_f32", ""))
        config = json.loads((ROOT / source / "sweep.json").read_text())
        command = planned.command
        fixed = command[command.index("--") + 1 :]
        assert fixed == config["fixed_flags"], planned.out
        assert command[command.index("--seed") + 1] == str(config["seed"])
        assert command[command.index("--total-timesteps") + 1] == str(config["total_timesteps"])
        assert [command[i + 1] for i, w in enumerate(command) if w == "--sample"] == config[
            "samples"
        ]
        if planned.first_look:  # the first look is what the folder held when the plan was fixed
            assert len(rows(ROOT / planned.out)) >= planned.first_look
    atari = [s for item in items if item.kind == "atari" for s in item.sweeps]
    assert {shlex.join(s.command[:2]) for s in atari} == {"-m a3c_tools.sweep"}
    assert all(s.runs == 3 for s in atari)


def test_an_items_wall_time_counts_sweeps_side_by_side_once(tmp_path):
    log = tmp_path / "SWEEPS.tsv"
    header = "item\tout\tstarted_utc\tended_utc\twall_s\truns_before\truns_after\tcpu\tcores\n"
    spans = [("c", "10:00:00", "10:30:00", "X", 16), ("c", "10:00:00", "10:30:00", "X", 16),
             ("c", "10:15:00", "11:00:00", "Y", 2), ("c", "12:00:00", "12:30:00", "Y", 2),
             ("a", "09:00:00", "09:06:00", "Y", 2)]  # fmt: skip
    rows = [f"{i}\tout\t2026-11-26 {a}\t2026-11-26 {b}\t0\t0\t0\t{cpu}\t{n}\n"
            for i, a, b, cpu, n in spans]  # fmt: skip
    log.write_text(header + "".join(rows))
    clocks = campaign.item_clocks(log)
    assert clocks["c"] == (1.5, ["X (16 cores)", "Y (2 cores)"])  # 10:00-11:00 and 12:00-12:30
    assert clocks["a"] == (0.1, ["Y (2 cores)"])


def test_a_running_sweeps_row_is_written_at_its_start_and_kept_current(line, tmp_path, monkeypatch):
    """A campaign killed outright (a session's end) leaves its last sweep's span in SWEEPS.tsv:
    the row is there from the sweep's start, its end kept current while it runs, and one row
    per sweep when it ends."""
    plan = extend_plan(tmp_path, line, 3)
    log = plan.parent / "SWEEPS.tsv"
    seen = []

    def slow_sweep(command):
        for _ in range(2):  # the table as a killed campaign would leave it, twice, 1.2 s apart
            with log.open(newline="") as f:
                seen.append(list(csv.DictReader(f, delimiter="\t")))
            time.sleep(1.2)
        return 0, ""

    monkeypatch.setattr(campaign, "LOG_EVERY_S", 0.05)
    monkeypatch.setattr(campaign, "execute", slow_sweep)
    run_main(campaign.main, [str(plan)])
    (first,), (second,) = seen
    assert (first["item"], first["out"], first["runs_before"]) == ("a1", str(line), "2")
    assert second["started_utc"] == first["started_utc"]
    assert second["ended_utc"] > first["ended_utc"] and float(second["wall_s"]) >= 1
    with log.open(newline="") as f:
        (final,) = list(csv.DictReader(f, delimiter="\t"))
    assert final["started_utc"] == first["started_utc"] and float(final["wall_s"]) >= 2


def test_a_sigterm_while_a_tool_runs_is_passed_on_to_it(tmp_path):
    """SIGTERM to the campaign (or a figure tool) reaches the sweep it runs, which stops its
    runs cleanly; the caller waits for it instead of dying and leaving it running."""
    ready = tmp_path / "ready"
    tool = textwrap.dedent(
        f"""
        import signal, sys, time
        def stop(*_):
            print("stopped cleanly", flush=True)
            sys.exit(130)
        signal.signal(signal.SIGTERM, stop)
        open({str(ready)!r}, "w").close()
        time.sleep(30)
        """
    )

    def terminate_when_ready():
        deadline = time.time() + 20
        while not ready.exists() and time.time() < deadline:
            time.sleep(0.01)
        os.kill(os.getpid(), signal.SIGTERM)

    before = signal.getsignal(signal.SIGTERM)
    threading.Thread(target=terminate_when_ready, daemon=True).start()
    started = time.time()
    code, stdout = figure_sweeps.execute(["-c", tool], capture=True)
    assert (code, stdout) == (130, "stopped cleanly\n")
    assert time.time() - started < 20 and signal.getsignal(signal.SIGTERM) == before


def test_a_line_whose_sweep_json_is_not_an_object_is_a_bad_plan(tmp_path):
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "sweep.json").write_text('{"script": "a3c_ff.py", "sam')  # truncated
    plan = write_plan(
        tmp_path,
        '[[item]]\nkind = "extend"\nid = "x"\ntitle = "t"\nruns = 3\n'
        f'lines = [{{ script = "agents/a3c_ff.py", out = "{bad}" }}]\n',
    )
    result = run_main(campaign.main, [str(plan)])
    assert result.returncode == 2, result.stderr
    assert (
        len(result.stderr.splitlines()) == 1 and "is not a sweep's configuration" in result.stderr
    )


def test_an_extend_never_takes_where_the_data_goes_from_a_sweep_json(line, tmp_path):
    """A line handed on whose sweep.json would send the runs' data to its writer's W&B entity:
    the campaign extends it with the rest of its configuration, its runs untracked, and one
    line says so (the stand-in agent takes no --track: a run given it would fail)."""
    config = json.loads((line / "sweep.json").read_text())
    tracked = ["--track", "--wandb-entity", "someone-else", "--wandb-project-name", "theirs"]
    config["fixed_flags"] = [*tracked, *config["fixed_flags"]]
    (line / "sweep.json").write_text(json.dumps(config))
    plan = extend_plan(tmp_path, line, 3)
    dry = run_main(campaign.main, [str(plan), "--dry-run"])
    assert dry.returncode == 0, dry.stderr
    (command,) = dry.stdout.splitlines()
    assert command.endswith(" -- --eval-interval 50")  # the rest of its fixed flags
    assert "track" not in command and "wandb" not in command and "someone-else" not in command
    assert dry.stderr == (
        f"note: {plan}: item 1: {line / 'sweep.json'} would send the runs' data elsewhere "
        f"({shlex.join(tracked)}); a campaign takes that from no file: its runs go untracked\n"
    )
    result = run_main(campaign.main, [str(plan)])
    assert result.returncode == 0, result.stderr
    assert [row["status"] for row in rows(line)] == ["ok", "ok", "ok"]
    assert "track" not in rows(line)[2]["flags"]


def test_a_plan_never_says_where_the_data_goes(line, tmp_path):
    agent = line.parent / "agents" / "a3c_ff.py"
    plan = write_plan(
        tmp_path,
        f"""
        [[item]]
        id = "s1"
        title = "a new line"
        kind = "sweep"
        runs = 1
        seed = 3
        total_timesteps = 100
        flags = ["--eval-interval", "50", "--track", "--wandb-entity=someone-else"]
        lines = [{{ script = "{agent}", out = "{tmp_path / "new"}" }}]
        """,
    )
    dry = run_main(campaign.main, [str(plan), "--dry-run"])
    assert dry.returncode == 0 and dry.stdout.endswith(" -- --eval-interval 50\n"), dry.stdout
    assert dry.stderr == (
        f"note: {plan}: item 1: the plan would send the runs' data elsewhere (--track "
        "--wandb-entity=someone-else); a campaign takes that from no file: its runs go untracked\n"
    )


@pytest.mark.parametrize(
    "change, said",
    [
        (lambda config: config.pop("seed"), "is not a sweep's configuration (it has no 'seed')"),
        (lambda config: config.update(samples="learning-rate=uniform:0:1"),
         "(its 'samples' is 'learning-rate=uniform:0:1', not a list of strings)"),
    ],
    ids=["no seed", "samples a string"],
)  # fmt: skip
def test_an_extend_of_a_sweep_json_without_a_field_it_uses_is_a_bad_plan(
    line, tmp_path, change, said
):
    config = json.loads((line / "sweep.json").read_text())
    change(config)
    (line / "sweep.json").write_text(json.dumps(config))
    plan = extend_plan(tmp_path, line, 3)
    for options in ([], ["--status"], ["--dry-run"]):
        result = run_main(campaign.main, [str(plan), *options])
        assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
        assert result.stderr.startswith(f"error: {plan}: item 1: {line / 'sweep.json'} ")
        assert said in result.stderr, result.stderr
    assert starts(line) == [] and not (plan.parent / "PROGRESS.md").exists()


@pytest.mark.parametrize(
    "text", ["a = " + "[" * 100_000, "a = " + "{ b = " * 100_000], ids=["arrays", "tables"]
)
def test_a_plan_nested_too_deep_is_one_line_and_exit_2(tmp_path, text):
    plan = tmp_path / "plan" / "plan.toml"
    plan.parent.mkdir()
    plan.write_text(text)
    result = run_main(campaign.main, [str(plan), "--status"])
    assert (result.returncode, result.stdout) == (2, "")
    assert result.stderr == f"error: {plan}: TOML nested too deep to read\n"
    assert sorted(plan.parent.iterdir()) == [plan]


@pytest.mark.parametrize(
    ("field", "says"),
    [
        ("seed = 1\n", "has no total_timesteps"),  # a sweep item without its steps
        ('seed = 1\ntotal_timesteps = "many"\n', "a field of another kind"),
        ("seed = [1]\ntotal_timesteps = 9\n", "a field of another kind"),
    ],
)
def test_an_item_missing_a_field_or_of_another_kind_is_one_line_and_exit_2(tmp_path, field, says):
    # (found by tests/test_loader_fuzz.py: a KeyError traceback before)
    plan = tmp_path / "plan" / "plan.toml"
    plan.parent.mkdir()
    plan.write_text('[[item]]\nid = "s"\ntitle = "t"\nkind = "sweep"\nruns = 2\n' + field
                    + 'lines = [{ script = "agents/a3c_ff.py", out = "results/x" }]\n')  # fmt: skip
    result = run_main(campaign.main, [str(plan), "--status"])
    assert (result.returncode, result.stdout) == (2, ""), result.stderr
    assert result.stderr.startswith(f"error: {plan}: item 1") and says in result.stderr
    assert result.stderr.count("\n") == 1
    assert sorted(plan.parent.iterdir()) == [plan]


def ff_and_online_plan(tmp_path: Path) -> Path:
    """A plan of a sweep item "s1" with two new lines, A3C FF into tmp_path/ff (a Catch sweep
    the batched backend takes) and online LWS into tmp_path/online (a future-work script it
    does not take), then the Atari item "b"."""
    ff, online = (
        ROOT / "agents" / "a3c_ff.py",
        ROOT / "agents" / "future_work" / "a3c_lws_online.py",
    )
    return write_plan(
        tmp_path,
        f"""
        [[item]]
        id = "s1"
        title = "a new line"
        kind = "sweep"
        runs = 2
        seed = 7500
        total_timesteps = 60
        samples = ["learning-rate=loguniform:1e-4:1e-2"]
        flags = ["--eval-interval", "30", "--eval-episodes", "3", "--t-max", "5"]
        lines = [{{ script = "{ff}", out = "{tmp_path / "ff"}" }},
                 {{ script = "{online}", out = "{tmp_path / "online"}" }}]

        {pong_item(tmp_path / "atari", ["vf1.0"])}
        """,
    )


def test_with_the_batched_backend_its_catch_sweeps_run_as_one_program(tmp_path):
    """--backend batched: a Catch sweep of a script the batched backend takes runs batched (its
    runs' closing lines say so, SWEEPS.tsv names the device); a future-work line (a script it
    does not take) and an Atari item stay on the process backend; --device without it is
    refused in one line."""
    ff = ROOT / "agents" / "a3c_ff.py"
    new = tmp_path / "ff"
    plan = ff_and_online_plan(tmp_path)
    printed = run_main(campaign.main, [str(plan), "--dry-run", "--backend", "batched"]).stdout
    commands = [shlex.split(line) for line in printed.splitlines()]
    batched = ["--backend", "batched", "--device", "cpu"]
    assert [" ".join(batched) in " ".join(c) for c in commands] == [True, False, False, False]
    refused = run_main(campaign.main, [str(plan), "--device", "cuda"])
    assert refused.returncode == 2 and "--device needs --backend batched" in refused.stderr
    ff_line = f'{{ script = "{ff}", out = "{new}" }}'
    ff_only = write_plan(tmp_path, plan.read_text().split("[[item]]\nid = \"b\"")[0].replace(
        plan.read_text().split("lines = ")[1].split("\n\n")[0], f"[{ff_line}]"))  # fmt: skip
    assert run_main(campaign.main, [str(ff_only), "--backend", "batched"]).returncode == 0
    assert [r["status"] for r in rows(new)] == ["ok", "ok"]
    for run in ("run-0000", "run-0001"):
        assert "batched with 2 runs" in (new / "runs" / run / "stdout.log").read_text()
    logged = (ff_only.parent / "SWEEPS.tsv").read_text().splitlines()[1].split("\t")
    assert logged[7].startswith("batched on cpu; ")


def backends_item(tmp_path: Path, backend: str) -> str:
    """A plan item of a study of the backends: two lines of FF, tmp_path/local on the process
    backend and tmp_path/batched on `backend`."""
    ff = ROOT / "agents" / "a3c_ff.py"
    return f"""
        [[item]]
        id = "g"
        title = "the backends"
        kind = "sweep"
        runs = 2
        seed = 7900
        total_timesteps = 100
        lines = [{{ script = "{ff}", out = "{tmp_path / "local"}" }},
                 {{ script = "{ff}", out = "{tmp_path / "batched"}", backend = "{backend}" }}]
        """


def test_a_line_that_names_the_batched_backend_runs_batched_on_the_campaigns_device(tmp_path):
    """A study of the backends: the plan's line says backend = "batched"; it runs so on the
    campaign's --device (cpu by default), its twin on the process backend; a backend the
    campaign lacks is a bad plan."""
    plan = write_plan(tmp_path, backends_item(tmp_path, "batched"))
    for extra, device in (([], "cpu"), (["--backend", "batched", "--device", "cuda"], "cuda")):
        printed = run_main(campaign.main, [str(plan), "--dry-run", *extra]).stdout.splitlines()
        wanted = f"--backend batched --device {device} --"
        assert [wanted in line for line in printed] == [extra != [], True], printed
    bad = run_main(campaign.main, [str(write_plan(tmp_path, backends_item(tmp_path, "ray")))])
    assert bad.returncode == 2 and "backend 'ray'; valid: local, batched" in bad.stderr


def test_a_batched_lines_runs_share_its_cpu_hours(tmp_path):
    """A batched line's runs ran as one batch on one core, each run's wall time the batch's: the
    line cost that wall time once, not once per run (the process line: each run's own)."""
    plan = write_plan(tmp_path, backends_item(tmp_path, "batched"))
    for out in ("local", "batched"):  # two finished runs, each an hour on its clock
        (tmp_path / out).mkdir()
        with (tmp_path / out / "results.csv").open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=["run_id", "status", "wall_time_s", "flags"])
            writer.writeheader()
            writer.writerows({"run_id": f"run-000{i}", "status": "ok", "wall_time_s": "3600",
                              "flags": "--num-workers 1"} for i in range(2))  # fmt: skip
    result = run_main(campaign.main, [str(plan), "--status"])
    assert result.returncode == 0, result.stderr
    assert "| g: the backends | 4 of 4 | 3.0 | 0.0 |" in result.stdout


@pytest.mark.parametrize("native", [True, False])
def test_the_cpu_column_says_whether_the_cpu_has_native_bf16(monkeypatch, native):
    """Two VMs both called "AMD EPYC" ran the campaign, one with native bf16 and one without,
    where `--precision auto` picks different precisions at K > 1: the column tells them apart."""
    from a3c_runtime import flags

    monkeypatch.setattr(flags, "native_bf16", lambda: native)
    assert campaign.cpu_model().endswith(", native bf16") is native


@pytest.mark.parametrize("native", [True, False])
def test_an_item_that_needs_native_bf16_runs_only_where_the_cpu_has_it(
    tmp_path, monkeypatch, capsys, native
):
    """An Atari item whose runs take --precision auto (bf16 at K > 1 on a CPU with native bf16,
    fp32 elsewhere) and says `needs_native_bf16`: on a CPU without it, its sweeps are not
    started (a line says why) and the plan is not done; on one with it, they run."""
    from a3c_runtime import flags

    monkeypatch.setattr(flags, "native_bf16", lambda: native)
    plan = write_plan(
        tmp_path, pong_item(tmp_path / "atari", ["vf1.0"]) + "needs_native_bf16 = true\n"
    )
    ran = []
    monkeypatch.setattr(campaign, "execute", lambda command: (ran.append(command[:2]), (0, ""))[1])
    result = run_main(campaign.main, [str(plan)])
    assert result.returncode == 1  # not done: either its runs are left, or the stand-in ran none
    assert bool(ran) is native
    assert ("== b: not run on this CPU" in result.stdout) is not native, result.stdout
    bad = write_plan(
        tmp_path, pong_item(tmp_path / "atari", ["vf1.0"]) + 'needs_native_bf16 = "yes"\n'
    )
    refused = run_main(campaign.main, [str(bad)])
    assert refused.returncode == 2 and "needs_native_bf16 must be true or false" in refused.stderr


def test_batchable_last_runs_what_a_gpu_could_not_batch_first(tmp_path, monkeypatch):
    """--batchable-last: the Catch sweeps the batched backend takes run after every other sweep
    (here the future-work line of the same item and the Atari item after it); without it the
    plan's order; with --backend batched it is refused in one line."""
    plan = ff_and_online_plan(tmp_path)
    ran = []
    monkeypatch.setattr(
        campaign, "run_logged", lambda plan, item, sweep: ran.append(sweep.out) or 0
    )
    monkeypatch.setattr(campaign, "execute", lambda command: (0, ""))  # the Atari figure's draw
    assert run_main(campaign.main, [str(plan)]).returncode == 1  # not finished: nothing ran
    in_plan_order = [p.name for p in ran]
    ran.clear()
    run_main(campaign.main, [str(plan), "--batchable-last"])
    assert in_plan_order[:2] == ["ff", "online"] and len(in_plan_order) == 3
    assert [p.name for p in ran][0] == "online" and [p.name for p in ran][-1] == "ff"
    printed = run_main(campaign.main, [str(plan), "--dry-run", "--batchable-last"]).stdout
    commands = [line for line in printed.splitlines() if "a3c_tools.sweep" in line]
    assert "a3c_lws_online.py" in commands[0] and "a3c_ff.py" in commands[-1]
    refused = run_main(campaign.main, [str(plan), "--batchable-last", "--backend", "batched"])
    assert refused.returncode == 2 and len(refused.stderr.strip().splitlines()) == 1
    assert "--batchable-last is for the process backend" in refused.stderr


def test_a_rate_from_without_committed_runs_is_a_bad_plan(tmp_path):
    ff = ROOT / "agents" / "a3c_ff.py"
    plan = write_plan(
        tmp_path,
        f"""
        [[item]]
        id = "s1"
        title = "a new line"
        kind = "sweep"
        runs = 2
        seed = 7500
        total_timesteps = 60
        lines = [{{ script = "{ff}", out = "{tmp_path / "ff"}" }}]
        rate_from = ["{tmp_path / "nowhere"}"]
        """,
    )
    result = run_main(campaign.main, [str(plan), "--status"])
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    assert "rate_from: no committed runs' rate" in result.stderr


@pytest.mark.parametrize("code", [130, 2])
def test_a_sweep_stopped_by_a_signal_or_refused_stops_the_campaign(tmp_path, monkeypatch, code):
    """A sweep that exits 130 (stopped by Ctrl-C or SIGTERM: its runs checkpointed) or 2 (its
    command refused) ends the campaign with that code: the next sweep is not started, so a
    session's end stops the campaign instead of its next run."""
    plan = ff_and_online_plan(tmp_path)
    ran = []
    monkeypatch.setattr(
        campaign, "run_logged", lambda plan, item, sweep: ran.append(sweep.out) or code
    )
    monkeypatch.setattr(campaign, "execute", lambda command: (0, ""))
    assert run_main(campaign.main, [str(plan)]).returncode == code
    assert [p.name for p in ran] == ["ff"]
