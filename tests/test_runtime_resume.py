"""a3c_runtime.resume: --resume continues the same experiment. Every flag comes from the
checkpoint; a flag that does not change the experiment may be given and is announced; any other
that differs is refused in one line; a checkpoint older than a flag still loads, saying so."""

import a3c_runtime as runtime
import pytest
from a3c_runtime.resume import RESUMABLE, given_flags, resumed_args
from conftest import (
    load_script,
    main_exit,
    read_checkpoint,
    rewrite_checkpoint,
    shared_for,
    tiny_args,
)

import catch_env  # noqa: F401  (registers Catch-v0)


@pytest.fixture
def trained(tmp_path):
    """A checkpoint of a3c_ff trained with flags other than the defaults."""
    module = load_script("a3c_ff")
    args = tiny_args(module, total_timesteps=300_000, learning_rate=3e-4, t_max=5, seed=7)
    path = tmp_path / "run" / "checkpoint.pt"
    path.parent.mkdir()
    runtime.save_checkpoint(path, shared_for(module, args), args, 1.0, script="a3c_ff.py")
    return module, runtime.load_checkpoint(str(path), module.AGENT), path


def test_given_flags_reads_the_command_line():
    module = load_script("a3c_ff")
    argv = ["--resume", "x.pt", "--total-timesteps=10", "--num-workers", "3", "--no-anneal-lr",
            "--capture-video", "7", "--not-a-flag"]  # fmt: skip
    assert given_flags(argv, module.Args) == {
        "resume", "total_timesteps", "num_workers", "anneal_lr", "capture_video"
    }  # fmt: skip


def test_every_flag_comes_from_the_checkpoint(trained, capsys):
    module, checkpoint, path = trained
    args = module.Args(resume=str(path))
    resumed = resumed_args(module.AGENT, checkpoint, args, given_flags(["--resume"], module.Args))
    assert (resumed.total_timesteps, resumed.learning_rate, resumed.t_max, resumed.seed) == (
        300_000, 3e-4, 5, 7
    )  # fmt: skip
    assert resumed.resume == str(path)
    assert capsys.readouterr().out == ""  # nothing changed, nothing to say


def test_a_flag_that_keeps_the_experiment_applies_and_is_announced(trained, capsys):
    module, checkpoint, path = trained
    argv = ["--resume", str(path), "--total-timesteps", "1000000", "--num-workers", "1"]
    args = module.Args(resume=str(path), total_timesteps=1_000_000, num_workers=1)
    resumed = resumed_args(module.AGENT, checkpoint, args, given_flags(argv, module.Args))
    assert resumed.total_timesteps == 1_000_000 and resumed.learning_rate == 3e-4
    out = capsys.readouterr().out
    assert out == "total_timesteps 300,000 -> 1,000,000\n"  # num_workers was 1 already


@pytest.mark.parametrize(
    ("flag", "value"),
    [("learning_rate", 0.5), ("t_max", 20), ("seed", 1), ("env", "BreakoutNoFrameskip-v4")],
)
def test_resumed_args_refuses_each_flag_that_changes_the_experiment(trained, flag, value):
    """The rule itself, before the command line's test below (which, were the flag let through,
    would train on for the checkpoint's 300,000 steps)."""
    module, checkpoint, path = trained
    args = module.Args(resume=str(path), **{flag: value})
    with pytest.raises(runtime.UsageError, match="differs from the run's"):
        resumed_args(module.AGENT, checkpoint, args, {"resume", flag})


@pytest.mark.parametrize("flags", [["--learning-rate", "0.5"], ["--t-max", "20"], ["--seed", "1"]])
def test_a_flag_that_changes_the_experiment_is_refused_in_one_line(
    trained, flags, monkeypatch, capsys
):
    module, _, path = trained
    monkeypatch.chdir(path.parent)
    code, err = main_exit(module, ["--resume", str(path), *flags], monkeypatch, capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith(f"error: {flags[0]} ") and "differs from the run's" in err
    assert {"learning-rate": "0.0003", "t-max": "5", "seed": "7"}[flags[0][2:]] in err
    # nothing written into the run (the folder's lock file, taken before the checkpoint was
    # read, is removed when the refusal releases it)
    assert sorted(p.name for p in path.parent.iterdir()) == ["checkpoint.pt"]


def test_the_same_value_of_any_flag_is_accepted(trained, capsys):
    module, checkpoint, path = trained
    argv = ["--resume", str(path), "--learning-rate", "0.0003", "--t-max", "5"]
    args = module.Args(resume=str(path), learning_rate=3e-4, t_max=5)
    resumed = resumed_args(module.AGENT, checkpoint, args, given_flags(argv, module.Args))
    assert resumed.learning_rate == 3e-4 and capsys.readouterr().out == ""


def test_a_checkpoint_older_than_a_flag_still_loads_stating_the_fallback(trained, capsys):
    module, checkpoint, path = trained
    del checkpoint.args["rms_init"], checkpoint.args["envs_per_worker"]  # as if older
    args = module.Args(resume=str(path))
    resumed = resumed_args(module.AGENT, checkpoint, args, {"resume"})
    assert resumed.rms_init == 0.0 and resumed.envs_per_worker == 1
    out = capsys.readouterr().out.splitlines()
    assert "note: the checkpoint predates --rms-init; the run goes on with 0.0" in out
    assert "note: the checkpoint predates --envs-per-worker; the run goes on with 1" in out


def test_the_resumable_flags_are_the_issues():
    assert {"total_timesteps", "time_limit", "num_workers", "eval_interval", "eval_episodes",
            "checkpoint_interval", "log_interval", "capture_video"} <= set(RESUMABLE)  # fmt: skip


def test_a_kept_time_limit_is_announced_with_how_to_change_it(trained, capsys):
    """A run started with --time-limit stops after as many seconds again when resumed: say so."""
    module, checkpoint, path = trained
    checkpoint.args["time_limit"] = 90.0
    args = module.Args(resume=str(path))
    resumed = resumed_args(module.AGENT, checkpoint, args, given_flags(["--resume"], module.Args))
    assert resumed.time_limit == 90.0
    assert capsys.readouterr().out == (
        "note: the run keeps its --time-limit 90.0: this part stops after that many seconds too; "
        "--time-limit SECONDS changes it, --time-limit None removes it\n"
    )
    for value, shown in (("300", "300.0"), ("None", "None")):
        argv = ["--resume", str(path), "--time-limit", value]
        limit = None if value == "None" else float(value)
        args = module.Args(resume=str(path), time_limit=limit)
        resumed = resumed_args(module.AGENT, checkpoint, args, given_flags(argv, module.Args))
        assert resumed.time_limit == limit
        assert capsys.readouterr().out == f"time_limit 90.0 -> {shown}\n"


def started_runs(monkeypatch) -> list:
    """The Args of each run the command line starts (train() replaced: nothing runs)."""
    started = []

    def train(agent, args, *rest):
        started.append(args)
        return {"outcome": "done"}

    monkeypatch.setattr("a3c_runtime.a3c.train", train)
    return started


def test_a_changed_flag_the_checkpoint_predates_is_refused_in_one_line(
    trained, monkeypatch, capsys
):
    """A flag newer than the checkpoint takes the run's value (its default here), and a given
    one that differs changes the experiment: refused as any other, not taken silently."""
    module, _, path = trained
    raw = read_checkpoint(path)
    del raw["args"]["rms_init"]  # as if written before --rms-init existed
    rewrite_checkpoint(path, raw)
    started = started_runs(monkeypatch)
    monkeypatch.chdir(path.parent)
    code, err = main_exit(module, ["--resume", str(path), "--rms-init", "1"], monkeypatch, capsys)
    assert code == 2 and err.count("\n") == 1, err
    assert err.startswith("error: --rms-init 1.0 differs from the run's 0.0: a resumed run keeps")
    assert started == []
    code, _ = main_exit(module, ["--resume", str(path), "--rms-init", "0"], monkeypatch, capsys)
    assert code == 0 and started[0].rms_init == 0.0  # the run's own value: the same run


TRACKED_ELSEWHERE = {"track": True, "wandb_entity": "someone-else", "wandb_project_name": "theirs"}
NOTE = (
    "note: the checkpoint's run was tracked (W&B entity 'someone-else', project 'theirs'); "
    "--resume takes where a run's data goes from the command line only: this part "
)


@pytest.mark.parametrize(
    ("flags", "tracking", "said"),
    [
        ([], (False, None, "deep-rl-video-games"),
         "is not tracked (--track, with --wandb-entity and --wandb-project-name, tracks it)"),
        (["--track"], (True, None, "deep-rl-video-games"),
         "logs to W&B entity yours (the default), project 'deep-rl-video-games'"),
        (["--track", "--wandb-project-name", "mine"], (True, None, "mine"),
         "logs to W&B entity yours (the default), project 'mine'"),
        (["--track", "--wandb-entity", "someone-else", "--wandb-project-name", "theirs"],
         (True, "someone-else", "theirs"), None),
        (["--no-track"], (False, None, "deep-rl-video-games"), None),
    ],
)  # fmt: skip
def test_a_resume_takes_where_the_data_goes_from_the_command_line_only(
    trained, flags, tracking, said, monkeypatch, capsys
):
    """A checkpoint handed on by someone whose run logged to their W&B entity: resumed here, the
    run logs only where this command line says (nowhere, by default), and a line says so
    wherever --resume once took the tracking, entity or project from the checkpoint."""
    module, _, path = trained
    raw = read_checkpoint(path)
    raw["args"].update(TRACKED_ELSEWHERE)
    rewrite_checkpoint(path, raw)
    started = started_runs(monkeypatch)
    monkeypatch.chdir(path.parent)
    argv = ["--resume", str(path), *flags]
    code, _ = main_exit(module, argv, monkeypatch, capsys, keep_out=True)
    out = capsys.readouterr().out
    assert code == 0, out
    (args,) = started
    assert (args.track, args.wandb_entity, args.wandb_project_name) == tracking
    notes = [line for line in out.splitlines() if "tracked" in line]
    assert notes == ([] if said is None else [NOTE + said])


def test_a_flag_of_where_the_data_goes_is_never_the_experiments(trained):
    """A sweep's run resumed with tracking of its own is still that run (its checkpoint is not
    taken for another run's)."""
    from a3c_runtime.resume import differing_flags

    module, checkpoint, path = trained
    checkpoint.args.update(TRACKED_ELSEWHERE)
    args = module.Args(**{**checkpoint.args, "track": False, "wandb_entity": None})
    assert differing_flags(module.AGENT, checkpoint, args) == []
