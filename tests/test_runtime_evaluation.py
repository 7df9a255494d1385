"""a3c_runtime.evaluation: the evaluator process and --evaluate."""

import dataclasses
import os
import pickle
import re
import signal
import warnings
from types import SimpleNamespace

import a3c_runtime as runtime
import gymnasium as gym
import numpy as np
import pytest
import torch
from a3c_runtime.resume import given_flags
from conftest import (
    FORK,
    SCRIPTS,
    load_script,
    main_exit,
    read_evaluations,
    run_script,
    shared_for,
    tiny_args,
)

import catch_env  # noqa: F401  (registers Catch-v0)


@pytest.mark.parametrize("name", SCRIPTS)
def test_the_evaluator_scores_the_copies_it_is_handed_in_order(name, tmp_path):
    """The evaluator evaluates each (step, theta) it is handed, in order, whatever the shared
    network holds meanwhile, and stops at None."""
    module = load_script(name)
    args = tiny_args(module, eval_episodes=2)
    shared = shared_for(module, args)
    initial = runtime.snapshots.copy_of(shared.model.state_dict())
    with torch.no_grad():
        for p in shared.params:
            p.fill_(float("nan"))  # what the workers did meanwhile must not matter
    requests, evaluations = FORK.Queue(), FORK.SimpleQueue()
    for step in (0, 500):
        requests.put(pickle.dumps((step, initial)))
    requests.put(None)
    runtime.evaluator(module.AGENT, shared, args, requests, str(tmp_path), evaluations)
    results = [evaluations.get(), evaluations.get()]
    assert [r["global_step"] for r in results] == [0, 500]
    assert all(len(r["scores"]) == 2 and all(s in (0, 1) for s in r["scores"]) for r in results)
    assert evaluations.empty()


def test_an_evaluation_is_the_same_at_the_same_step():
    """Its episodes' seeds and sampled actions come from --seed and the step: the evaluation of
    a step in a resumed run is the one the run that went on took."""
    module = load_script("a3c_ff")
    args = tiny_args(module, eval_episodes=6)
    torch.manual_seed(0)
    model = module.AGENT.build_network(3, args)

    def scores(step: int, seed: int) -> list[float]:
        envs = runtime.make_eval_envs(module.AGENT, args, None)
        torch.manual_seed(step)  # the process's own generator must not matter
        evaluated = runtime.evaluate_network(model, envs, step, dataclass_replace(args, seed))
        return evaluated["scores"]

    assert scores(1000, 1) == scores(1000, 1)
    assert len({tuple(scores(step, seed)) for step, seed in ((1000, 1), (2000, 1), (1000, 2))}) > 1


def dataclass_replace(args, seed: int):
    import dataclasses

    return dataclasses.replace(args, seed=seed)


def test_evaluate_plays_the_runs_protocol_or_a_handful_of_episodes_when_rendering():
    module = load_script("a3c_ff")
    trained = tiny_args(module, eval_episodes=7, seed=3, eval_greedy=True)
    protocol = runtime.evaluation.evaluation_protocol

    def command(*flags: str, **values):
        return module.Args(**values), given_flags(list(flags), module.Args)

    run = protocol(trained, *command())
    assert (run.eval_episodes, run.seed, run.eval_greedy) == (7, 3, True)  # the run's own
    watched = protocol(trained, *command("--render", "human", render="human"))
    assert watched.eval_episodes == runtime.evaluation.HUMAN_EVAL_EPISODES == 5
    given = protocol(trained, *command("--eval-episodes", "4", "--seed", "1", "--no-eval-greedy",
                                       eval_episodes=4, seed=1, eval_greedy=False))  # fmt: skip
    assert (given.eval_episodes, given.seed, given.eval_greedy) == (4, 1, False)


class ActionCountingEnv:
    """20 steps; the score is how often action 1 was taken."""

    def reset(self, seed=None):
        self.t, self.ones = 0, 0
        return torch.zeros(4, 84, 84, dtype=torch.uint8).numpy(), {}

    def step(self, action):
        self.t, self.ones = self.t + 1, self.ones + (action == 1)
        done = self.t == 20
        obs = torch.zeros(4, 84, 84, dtype=torch.uint8).numpy()
        return obs, 0.0, done, False, {"episode": {"r": float(self.ones), "l": self.t}}


class FixedPolicy(torch.nn.Module):
    """pi = (0.4, 0.6) in every state."""

    def forward(self, obs):
        log_probs = torch.tensor([0.4, 0.6]).log().expand(len(obs), 2)
        return log_probs, torch.zeros(len(obs))


class IdEnv:
    """An episode of `length` steps whose frames show the env's `id`; the score is how often
    action 1 was taken."""

    def __init__(self, id: int, length: int):
        self.id, self.length = id, length

    def reset(self, seed=None):
        self.t, self.ones = 0, 0
        return np.full((4, 84, 84), self.id, dtype=np.uint8), {}

    def step(self, action):
        self.t, self.ones = self.t + 1, self.ones + (action == 1)
        obs = np.full((4, 84, 84), self.id, dtype=np.uint8)
        episode = {"r": float(self.ones), "l": self.t}
        return obs, 0.0, self.t == self.length, False, {"episode": episode}


class RowSums(torch.nn.Module):
    """A recurrent policy whose state row sums the ids its episode's frames show: argmax pi is
    action 1 exactly when the sum is a multiple of the frame's id, as it is while the row holds
    its own episode's state (the ids are primes)."""

    def initial_state(self, n):
        return (torch.zeros(n),)

    def forward(self, batch, state):
        ids = batch[0, :, 0, 0, 0].double()
        sums = state[0] + ids
        own = (sums % ids == 0)[:, None]
        log_probs = torch.where(own, torch.tensor([-5.0, 0.0]), torch.tensor([0.0, -5.0]))
        return log_probs[None], torch.zeros(1, len(ids)), (sums,)


def test_a_recurrent_evaluation_keeps_each_running_episodes_own_state_row():
    """Episodes of different lengths in one batched evaluation (as on Atari): when one ends,
    each episode still running keeps its own state row, not the row at its new position."""
    envs = [IdEnv(id, length) for id, length in ((2, 2), (3, 6), (5, 4), (7, 9))]
    scores = runtime.play_episodes(RowSums(), envs, greedy=True)
    assert scores.tolist() == [2.0, 6.0, 4.0, 9.0]


def test_greedy_evaluation_plays_argmax_pi():
    """--eval-greedy: action 1 (pi 0.6) at every step; sampling (seeded) takes action 0 about
    40% of the time."""
    torch.manual_seed(0)
    envs = [ActionCountingEnv() for _ in range(4)]
    greedy = runtime.play_episodes(FixedPolicy(), envs, greedy=True)
    assert greedy.tolist() == [20.0] * 4
    sampled = runtime.play_episodes(FixedPolicy(), envs)
    assert 4 * 20 * 0.3 < sampled.sum() < 4 * 20 * 0.9


def test_evaluate_in_a_window_without_a_display_exits_2_in_one_line(tmp_path, monkeypatch, capsys):
    """Without a display SDL would play the episodes in no window at all."""
    module = load_script("a3c_ff")
    args = tiny_args(module)
    path = tmp_path / "checkpoint.pt"
    runtime.save_checkpoint(path, shared_for(module, args), args, 1.0, script="a3c_ff.py")
    for name in ("SDL_VIDEODRIVER", "DISPLAY", "WAYLAND_DISPLAY"):
        monkeypatch.delenv(name, raising=False)
    argv = ["--evaluate", str(path), "--render", "human"]
    code, err = main_exit(module, argv, monkeypatch, capsys)
    assert code == 2 and err.startswith("error: no display: ") and err.count("\n") == 1, err


def test_evaluate_refuses_a_flag_the_checkpoint_contradicts(tmp_path, monkeypatch, capsys):
    """--evaluate plays the checkpoint's env and network: a flag given with another value than
    the checkpoint's is refused in one line, naming the flags that apply; the same value, or
    one of those flags, plays."""
    module = load_script("a3c_ff")
    args = tiny_args(module)
    path = tmp_path / "checkpoint.pt"
    runtime.save_checkpoint(path, shared_for(module, args), args, 1.0, script="a3c_ff.py")
    for flags, shown in ((["--env", "BreakoutNoFrameskip-v4"], "--env BreakoutNoFrameskip-v4"),
                         (["--learning-rate", "0.5"], "--learning-rate 0.5"),
                         (["--activation", "elu"], "--activation elu")):  # fmt: skip
        code, err = main_exit(module, ["--evaluate", str(path), *flags], monkeypatch, capsys)
        assert code == 2 and err.count("\n") == 1, err
        assert err.startswith(f"error: {shown} differs from the checkpoint's "), err
        assert "only --seed, --eval-episodes, --eval-greedy, --render, --capture-video" in err
    argv = ["--evaluate", str(path), "--env", "Catch-v0", "--seed", "4", "--eval-episodes", "1"]
    code, err = main_exit(module, argv, monkeypatch, capsys)
    assert code == 0 and err == "", err


def test_evaluate_sets_glpqs_progress_to_the_checkpoints_share_of_t_max(
    tmp_path, monkeypatch, capsys
):
    """--evaluate plays a GLPQ checkpoint at the temperature of its step: progress T / T_max."""
    module = load_script("a3c_glpq")
    args = tiny_args(module)
    shared = shared_for(module, args)
    shared.base_step[0] = 3 * args.total_timesteps // 4
    path = tmp_path / "checkpoint.pt"
    runtime.save_checkpoint(path, shared, args, 1.0, script="a3c_glpq.py")
    progress = []
    monkeypatch.setattr(module.ActorCritic, "set_progress", lambda self, p: progress.append(p))
    argv = ["--evaluate", str(path), "--eval-episodes", "1"]
    code, err = main_exit(module, argv, monkeypatch, capsys)
    assert code == 0, err
    assert progress == [pytest.approx(0.75)]


@pytest.mark.parametrize("capture", [False, True])
def test_the_evaluator_records_videos_only_with_capture_video(tmp_path, monkeypatch, capture):
    module = load_script("a3c_ff")
    args = tiny_args(module, capture_video=capture)
    asked = []

    def make_eval_envs(agent, args, video_dir, prefix="rl-video"):
        asked.append(video_dir)
        raise KeyboardInterrupt  # enough: the evaluator has said where its videos go

    monkeypatch.setattr(runtime.evaluation, "make_eval_envs", make_eval_envs)
    with pytest.raises(KeyboardInterrupt):
        runtime.evaluation.evaluator(
            module.AGENT, shared_for(module, args), args, None, str(tmp_path), None
        )
    assert asked == [str(tmp_path / "videos") if capture else None]


def test_evaluate_of_a_runs_final_checkpoint_gives_its_final_evaluation(
    tmp_path, monkeypatch, capsys
):
    """The same episodes (their seeds), the same action samples and the same episode count as
    the run's own final evaluation: the same scores."""
    run_dir = tmp_path / "run"
    flags = ["--num-workers", "1", "--total-timesteps", "400", "--eval-interval", "200",
             "--eval-episodes", "8", "--seed", "3", "--run-dir", str(run_dir)]  # fmt: skip
    result = run_script("a3c_ff", *flags)
    assert result.returncode == 0, result.stderr
    final = read_evaluations(run_dir)[-1]
    assert int(final["global_step"]) >= 400 and final["episodes"] == "8"
    argv = ["--evaluate", str(run_dir / "checkpoint.pt")]
    code, _ = main_exit(load_script("a3c_ff"), argv, monkeypatch, capsys, keep_out=True)
    out = capsys.readouterr().out
    assert code == 0, out
    scores = [float(line.split()[-1]) for line in out.splitlines() if line.startswith("episode")]
    assert len(scores) == 8 and f"step {int(final['global_step']):,}: mean score" in out, out
    assert np.mean(scores) == float(final["mean_return"])
    assert np.std(scores) == float(final["std_return"])


class SeedRecordingEnv(ActionCountingEnv):
    """ActionCountingEnv that records the seed of each reset."""

    def __init__(self):
        self.seeds = []

    def reset(self, seed=None):
        self.seeds.append(seed)
        return super().reset(seed)


def protocol_args(**flags) -> SimpleNamespace:
    """What evaluate_network reads of a run's flags."""
    return SimpleNamespace(**{"seed": 1, "total_timesteps": 10_000, "eval_greedy": False, **flags})


def test_the_run_evaluates_with_argmax_pi_under_eval_greedy():
    """The run's evaluations (evaluate_network, the evaluator's) play argmax pi with
    --eval-greedy (every action 1, pi 0.6) and sample pi without it."""
    envs = [ActionCountingEnv() for _ in range(4)]
    greedy = runtime.evaluate_network(FixedPolicy(), envs, 1000, protocol_args(eval_greedy=True))
    assert greedy["scores"] == [20.0] * 4
    sampled = runtime.evaluate_network(FixedPolicy(), envs, 1000, protocol_args())
    assert 4 * 20 * 0.3 < sum(sampled["scores"]) < 4 * 20 * 0.9


def test_each_evaluation_plays_other_episodes_than_the_last():
    """The episodes' seeds and sampled actions depend on the step: the 20 evaluations of a run
    are 20 draws of the protocol, not the same episodes 20 times (and the same step gives the
    same ones again)."""
    envs = [SeedRecordingEnv() for _ in range(4)]

    def evaluated(step: int) -> tuple[list, list]:
        scores = runtime.evaluate_network(FixedPolicy(), envs, step, protocol_args())["scores"]
        return [env.seeds[-1] for env in envs], scores

    first, second, again = evaluated(1000), evaluated(2000), evaluated(1000)
    assert first == again
    assert set(first[0]).isdisjoint(second[0]) and first[1] != second[1]


def test_with_a_video_folder_the_first_evaluation_env_records_or_with_every_each(tmp_path):
    """--capture-video: the final evaluation's first episode is recorded (its first env wraps
    RecordVideo), the others not; --evaluate's `every` records each env's under its own name,
    in one folder, with no warning that a recorder's folder exists (each has its own names)."""
    module = load_script("a3c_ff")
    args = tiny_args(module, eval_episodes=3)
    first = runtime.make_eval_envs(module.AGENT, args, str(tmp_path / "v"), prefix="final")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        every = runtime.make_eval_envs(module.AGENT, args, str(tmp_path / "w"), every=True)
    plain = runtime.make_eval_envs(module.AGENT, args, None)
    try:
        assert [isinstance(e, gym.wrappers.RecordVideo) for e in first] == [True, False, False]
        assert first[0].name_prefix == "final"
        assert [e.name_prefix for e in every] == ["rl-video-1", "rl-video-2", "rl-video-3"]
        assert not any(isinstance(e, gym.wrappers.RecordVideo) for e in plain)
    finally:
        for env in (*first, *every, *plain):
            env.close()


def test_evaluate_with_capture_video_records_each_episode_beside_the_checkpoint(
    tmp_path, monkeypatch, capsys
):
    """--evaluate CKPT --capture-video: every episode recorded, each under its own name, in
    videos-evaluate/ of the checkpoint's folder (the envs' video folder is what is checked: the
    recording itself is the slow tier's)."""
    module = load_script("a3c_ff")
    args = tiny_args(module)
    path = tmp_path / "run" / "checkpoint.pt"
    path.parent.mkdir()
    runtime.save_checkpoint(path, shared_for(module, args), args, 1.0, script="a3c_ff.py")
    asked, make = [], runtime.evaluation.make_eval_envs

    def make_eval_envs(agent, protocol, video_dir, prefix="rl-video", every=False):
        asked.append((video_dir, prefix, every))
        return make(agent, protocol, None)

    monkeypatch.setattr(runtime.evaluation, "make_eval_envs", make_eval_envs)
    argv = ["--evaluate", str(path), "--capture-video", "--eval-episodes", "2"]
    code, err = main_exit(module, argv, monkeypatch, capsys)
    assert code == 0, err
    assert asked == [(str(tmp_path / "run" / "videos-evaluate"), "episode", True)]


class EndingEnv(IdEnv):
    """IdEnv that can be closed and that sends this process `signum` at its `at`-th step (counted
    over all its episodes), as Ctrl-C or `kill` would while --evaluate plays."""

    def __init__(self, id: int, length: int, signum: int | None = None, at: int = 0):
        super().__init__(id, length)
        self.signum, self.at, self.steps = signum, at, 0

    def step(self, action):
        self.steps += 1
        if self.signum is not None and self.steps == self.at:
            os.kill(os.getpid(), self.signum)
        return super().step(action)

    def close(self):
        pass


def evaluate_with_envs(tmp_path, monkeypatch, capsys, envs, window=False) -> tuple[int, str, str]:
    """`--evaluate` of a Catch checkpoint in process, its episodes played in `envs` (a list, or
    with `window` one env played once per episode as in --render human): (exit code, stdout,
    stderr)."""
    module = load_script("a3c_ff")
    args = tiny_args(module)
    path = tmp_path / "checkpoint.pt"
    runtime.save_checkpoint(path, shared_for(module, args), args, 1.0, script="a3c_ff.py")
    argv = ["--evaluate", str(path), "--eval-episodes", str(len(envs))]
    if window:
        make_env = module.AGENT.make_env

        def window_env(env_id, render_mode=None):
            return envs[0] if render_mode == "human" else make_env(env_id)

        monkeypatch.setattr("catch_env.rendering.check_display", lambda: None)
        monkeypatch.setattr(module, "AGENT", dataclasses.replace(module.AGENT, make_env=window_env))
        argv += ["--render", "human"]
    else:
        monkeypatch.setattr(runtime.evaluation, "make_eval_envs", lambda *_a, **_k: envs)
    code, _ = main_exit(module, argv, monkeypatch, capsys, keep_out=True)
    out, err = capsys.readouterr()
    return code, out, err


def test_evaluate_prints_each_score_as_its_episode_ends(tmp_path, monkeypatch, capsys):
    """The episodes of a batch end far apart (minutes on Atari): a line says what is played,
    then each episode's score comes as it ends, shortest first, and the mean after the last."""
    envs = [EndingEnv(2, 9), EndingEnv(3, 2), EndingEnv(5, 5)]
    code, out, err = evaluate_with_envs(tmp_path, monkeypatch, capsys, envs)
    assert code == 0 and err == "", err
    lines = out.splitlines()
    assert lines[0] == ("Catch-v0, step 0: 3 episodes (sampling from pi), at once, each score "
                        "as its episode ends")  # fmt: skip
    assert [line.split(":")[0] for line in lines[1:4]] == ["episode 2", "episode 3", "episode 1"]
    assert re.fullmatch(r"Catch-v0, step 0: mean score [\d.]+ \+- [\d.]+ over 3 episodes", lines[4])


class ThreadCountingEnv(EndingEnv):
    """EndingEnv that records torch's thread count at each step."""

    threads: list[int] = []

    def step(self, action):
        self.threads.append(torch.get_num_threads())
        return super().step(action)


def test_evaluate_plays_on_one_thread_as_the_runs_evaluations(tmp_path, monkeypatch, capsys):
    """The run's evaluator and final evaluation play on one torch thread; so does --evaluate
    (on a shared CPU, a second thread made it 6x slower)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(2)
    try:
        envs = [ThreadCountingEnv(2, 3), ThreadCountingEnv(3, 4)]
        code, _, err = evaluate_with_envs(tmp_path, monkeypatch, capsys, envs)
    finally:
        torch.set_num_threads(threads)
    assert code == 0, err
    assert set(ThreadCountingEnv.threads) == {1}


@pytest.mark.parametrize("window", [False, True], ids=["batch", "window"])
@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_stops_evaluate_keeping_the_episodes_that_ended(
    tmp_path, monkeypatch, capsys, signum, window
):
    """Ctrl-C or SIGTERM mid-evaluation: the scores of the episodes that ended, a line saying
    where it stopped, their mean, exit code 0 as a stopped run's, no traceback; the signal
    handlers are given back."""
    if window:  # one env, 3 episodes of 4 steps: the signal comes in the second
        envs, ended = [EndingEnv(2, 4, signum, at=6)] * 3, 1
    else:  # 4 at once: the two short ones end before the signal
        envs, ended = [EndingEnv(2, 2), EndingEnv(3, 3), EndingEnv(5, 50, signum, at=10),
                       EndingEnv(7, 60)], 2  # fmt: skip

    def unhandled(_signum, _frame):  # (without this, a SIGTERM evaluate ignores ends pytest)
        raise AssertionError("the signal reached the caller: --evaluate did not take it")

    previous = signal.signal(signum, unhandled)
    try:
        code, out, err = evaluate_with_envs(tmp_path, monkeypatch, capsys, envs, window)
        assert signal.getsignal(signum) is unhandled
    finally:
        signal.signal(signum, previous)
    assert code == 0 and err == "", err
    lines = out.splitlines()[1:]
    assert [line.split(":")[0] for line in lines[:ended]] == [
        f"episode {i + 1}" for i in range(ended)
    ]
    name, total = signal.Signals(signum).name, len(envs)
    assert lines[ended] == f"stopped by {name} after {ended} of {total} episodes"
    assert re.fullmatch(
        rf"Catch-v0, step 0: mean score [\d.]+ \+- [\d.]+ over the {ended} of {total} episodes "
        "that ended",
        lines[ended + 1],
    )
    assert len(lines) == ended + 2
