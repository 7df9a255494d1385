"""The batched backend (a3c_runtime.batched, the sweep's a3c_tools.batched) and its torch Catch
(catch_env.torch_catch): the torch env against catch_env's NumPy env game for game, and run i
of the batched backend against the script's own one-worker run with the same seed and flags,
action for action and parameter for parameter."""

import csv
import dataclasses
import errno
import itertools
import os
import signal
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch
from a3c_runtime import UsageError as RunUsageError
from a3c_runtime import (
    WriteFailed,
    evaluate_network,
    load_checkpoint,
    make_eval_envs,
    seed_everything,
)
from a3c_runtime import batched as runtime_batched
from a3c_runtime.batchable import resolve_run_args
from a3c_runtime.batched import BatchedA3C, BatchedRun, train_batched
from a3c_runtime.snapshots import saved_state
from a3c_tools import parsed_flags, sweep
from a3c_tools.batched import probe, resumable_checkpoint
from conftest import (
    FORK,
    ROOT,
    load_script,
    main_exit,
    read_checkpoint,
    read_evaluations,
    rewrite_checkpoint,
    run_main,
    shared_for,
    tiny_args,
)
from hypothesis import example, given, settings
from hypothesis import strategies as st

from catch_env.torch_catch import NumpyStateView, TorchCatchVectorEnv
from catch_env.wrappers import make_vector_env


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """One thread, as a worker's torch: small ops on a shared 2-core machine run fastest so."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


# --- Catch-v0 in torch against catch_env's NumPy env -------------------------------------------


def play_both(seeds: list[int], steps: int, action_seed: int) -> None:
    """Step the torch env and the NumPy env (make_vector_env, as the scripts' workers make it)
    with the same seeds and random actions; every observation, reward, termination, final
    observation and episode statistic is the same."""
    numpy_envs = make_vector_env("Catch-v0", len(seeds))
    torch_envs = TorchCatchVectorEnv(len(seeds))
    obs, _ = numpy_envs.reset(seed=seeds)
    np.testing.assert_array_equal(torch_envs.reset(seed=seeds).numpy(), obs)
    rng = np.random.default_rng(action_seed)
    episodes = 0
    for _ in range(steps):
        actions = rng.integers(3, size=len(seeds))
        obs, rewards, terminated, truncated, info = numpy_envs.step(actions)
        t_obs, t_rewards, t_terminated, ended = torch_envs.step(torch.from_numpy(actions))
        np.testing.assert_array_equal(t_obs.numpy(), obs)
        np.testing.assert_array_equal(t_rewards.numpy(), rewards)
        np.testing.assert_array_equal(t_terminated.numpy(), terminated)
        np.testing.assert_array_equal(ended, terminated | truncated)
        if ended.any():
            episodes += int(ended.sum())
            for i in np.flatnonzero(ended):
                np.testing.assert_array_equal(torch_envs.final_obs[i].numpy(), info["final_obs"][i])
            episode = info["final_info"]["episode"]
            np.testing.assert_array_equal(
                torch_envs.final_returns.numpy()[ended], episode["r"][ended]
            )
            np.testing.assert_array_equal(
                torch_envs.final_lengths.numpy()[ended], episode["l"][ended]
            )
    assert episodes == len(seeds) * (steps // 15)


def test_torch_catch_plays_the_numpy_games_over_many_episodes():
    """8 games, 70 episodes each (more than one block of 64 start states per game)."""
    play_both([3, 1_000_003, 7, 2**31 - 1, 0, 42, 99, 12_345], 70 * 15, action_seed=0)


@settings(max_examples=15, deadline=None)
@given(
    seeds=st.lists(st.integers(0, 2**32 - 1), min_size=1, max_size=5),
    episodes=st.integers(1, 5),
    action_seed=st.integers(0, 2**16),
)
def test_torch_catch_equals_the_numpy_env_for_any_seeds_and_actions(seeds, episodes, action_seed):
    play_both(seeds, episodes * 15 + 7, action_seed)


def test_a_torch_games_numpy_state_continues_in_the_numpy_env():
    """numpy_state(i) is game i as the script's one-game env holds it: set into a NumPy env, it
    plays on as the torch game does (frames, rewards, new games' start states); and
    set_numpy_state reads it back."""
    torch_envs = TorchCatchVectorEnv(3)
    torch_envs.reset(seed=[5, 6, 7])
    rng = np.random.default_rng(1)
    for _ in range(20):  # mid-episode, after an episode ended
        torch_envs.step(torch.from_numpy(rng.integers(3, size=3)))
    numpy_env = make_vector_env("Catch-v0", 1)
    numpy_env.reset(seed=0)
    numpy_env.set_state(NumpyStateView(torch_envs, 1).get_state())
    copy = TorchCatchVectorEnv(1)
    copy.reset(seed=0)
    copy.set_numpy_state(0, torch_envs.numpy_state(1))
    for _ in range(100):
        actions = rng.integers(3, size=3)
        t_obs, t_rewards, _, _ = torch_envs.step(torch.from_numpy(actions))
        obs, rewards, *_ = numpy_env.step(actions[1:2])
        c_obs, c_rewards, _, _ = copy.step(torch.from_numpy(actions[1:2]))
        np.testing.assert_array_equal(t_obs[1].numpy(), obs[0])
        np.testing.assert_array_equal(c_obs[0].numpy(), obs[0])
        assert t_rewards[1] == rewards[0] == c_rewards[0]


# --- Run i of the batched backend is the script's one-worker run --------------------------------


def script_update(module, shared, batch, i: int) -> tuple[torch.Tensor, list, list, tuple]:
    """One update of the script's own one-worker loop (module.worker), from run i's state in the
    batch as its checkpoint holds it (theta, the RMSprop statistics, the step, the worker's
    generator, env and frames, an LSTM's state): its actions, theta and statistics after it,
    and its worker's state as its loop ends. `shared`: a Shared of the run's Args, reused."""
    with torch.no_grad():
        for p, q in zip(shared.params, batch.params, strict=True):
            p.copy_(q[i])
        for s, q in zip(shared.optimizer.square_avg, batch.optimizer.square_avg, strict=True):
            s.copy_(q[i])
    shared.steps.zero_()
    shared.base_step[0] = batch.step_count
    shared.stop.clear()
    shared.marks.resumed_states = {0: saved_state(BatchedA3C.worker_state(batch, i))}
    taken, loss, finished = [], module.a3c_loss, []
    shared.finish_worker = lambda _, worker_state: finished.append(worker_state())

    def recorded_loss(log_probs, actions, *rest):
        taken.append(actions.clone())
        return loss(log_probs, actions, *rest)

    module.a3c_loss = recorded_loss
    try:
        module.worker(0, shared, args=shared.args)
    finally:
        module.a3c_loss = loss
    params = [p.detach().clone() for p in shared.params]
    return taken[0], params, shared.optimizer.square_avg, finished[0]


def one_update_shared(module, args, monkeypatch):
    """A Shared of a run with these Args whose worker stops after one update; its env is made
    once (the worker sets its state from the batch's)."""
    shared = shared_for(module, args)
    shared.args = args
    envs = module.make_vector_env(args.env, 1)
    monkeypatch.setattr(module, "make_vector_env", lambda *_: envs)
    optimizer_step = shared.optimizer.step

    def one_step(grads, lr):
        optimizer_step(grads, lr)
        shared.stop.set()

    shared.optimizer.step = one_step
    return shared


def steps_of(updates: int, t_max: int) -> int:
    """The steps of a one-env run's first `updates` updates: Catch's 15-step episodes cut into
    rollouts of t_max steps (7, 7, 1 for 7)."""
    episode = [min(t_max, 15 - start) for start in range(0, 15, t_max)]
    return sum(itertools.islice(itertools.cycle(episode), updates))


def run_args(module, flags: dict, steps: int, seeds_and_rates) -> list:
    return [
        tiny_args(
            module, seed=seed, learning_rate=lr, total_timesteps=steps, precision="fp32", **flags
        )
        for seed, lr in seeds_and_rates
    ]


RUN_FLAGS = [(1, 7e-4), (1001, 3e-3)]  # per-run seeds and learning rates
UPDATES = 50
OTHER_NETWORKS = ("a3c_lws", "a3c_ss", "a3c_ww", "a3c_lpq", "a3c_glpq")  # (LSTM: below)
# LWS as its Figure 6.3 runs ran it, "LWS S" (fixed centroids on a grid: buffers drawn from
# each run's seed, stacked per run)
LWS_AS_RUN = {"lws_similarity": "matrix", "lws_padding": "same", "lws_second_layer_maps": 32,
              "lws_kernel_init": "uniform-sqrt3", "lws_kcps": 4, "lws_centroid_init": "grid",
              "lws_centroids": "group", "lws_trainable": False}  # fmt: skip
BATCH_FLAGS = [
    {"t_max": 5},  # rollouts of 5 steps, bootstrapped from V(s_5) twice per episode
    {"t_max": 20, "grad_clip_mode": "global-norm", "activation": "elu"},  # whole episodes
    {"t_max": 5, "grad_clip_mode": "value", "grad_clip": 0.5, "value_loss_form": "text",
     "weight_init": "variance-scaling", "anneal_lr": False, "rms_init": 1.0},
]  # fmt: skip


@pytest.mark.parametrize(
    ("name", "flags", "updates", "conv_form"),
    [
        # FF at its defaults, 50 updates; the other networks the backend batches (GLPQ with
        # its tau schedule and 1/tau loss correction) at theirs, 10 updates (they share FF's
        # worker loop, so 50 of theirs would add CI time and no code); FF's other flags in the
        # slow tier, 10 updates
        ("a3c_ff", BATCH_FLAGS[0], UPDATES, "grouped"),
        *((name, BATCH_FLAGS[0], 10, "grouped") for name in OTHER_NETWORKS),
        ("a3c_lws", {**BATCH_FLAGS[0], **LWS_AS_RUN}, 10, "grouped"),
        ("a3c_lws", {**BATCH_FLAGS[0], "lws_trainable": False}, 10, "grouped"),  # U[0,1] per seed
        # LSTM with rollouts of 7, 7 and 1 steps: a one-step learning pass, and its state carried
        # over two rollouts of an episode and zeroed at its end
        ("a3c_lstm", {"t_max": 7}, 9, "grouped"),
        *(
            pytest.param("a3c_ff", flags, 10, "grouped", marks=pytest.mark.slow)
            for flags in BATCH_FLAGS[1:]
        ),  # fmt: skip
        # the convolutions as matmuls (conv_form's option): FF, LSTM and LWS's locally shared
        # layers (the other networks' convolutions are FF's: tests/test_stacked_convs.py checks
        # each network's forward with them)
        ("a3c_ff", BATCH_FLAGS[0], UPDATES, "matmul"),
        ("a3c_lstm", {"t_max": 7}, 9, "matmul"),
        ("a3c_lws", {**BATCH_FLAGS[0], **LWS_AS_RUN}, 10, "matmul"),
    ],
)
def test_each_update_of_run_i_is_the_scripts_update_from_its_state(
    name, flags, updates, conv_form, monkeypatch
):
    """Two runs with their own seeds and learning rates as one batch, 10 or 50 updates: before
    each one, run i's state is handed to the script's own loop as its checkpoint would hand it
    (theta, RMSprop statistics, step, the worker's generator, env and frames); the script's
    update takes the batch's actions, and ends with its theta and statistics to float
    tolerance (only the order of floating-point sums differs), its convolutions computed either
    way (conv_form)."""
    module = load_script(name)
    steps = steps_of(updates, flags["t_max"])
    runs_args = run_args(module, flags, steps, RUN_FLAGS)
    batch = BatchedA3C(module, [BatchedRun(args) for args in runs_args], "cpu", conv_form)
    assert batch.conv_form == conv_form
    shareds = [one_update_shared(module, args, monkeypatch) for args in runs_args]
    for _ in range(updates):
        expected = [script_update(module, shared, batch, i) for i, shared in enumerate(shareds)]
        batch.update()
        for i, (actions, params, square_avg, worker) in enumerate(expected):
            np.testing.assert_array_equal(batch.last_actions[i].numpy(), actions.numpy())
            for p, q in zip(batch.params, params, strict=True):
                torch.testing.assert_close(p[i], q, rtol=1e-5, atol=1e-5)
            for s, q in zip(batch.optimizer.square_avg, square_avg, strict=True):
                torch.testing.assert_close(s[i], q, rtol=1e-4, atol=1e-6)
            # the state the run carries on (LSTM: zeroed where its episode ended)
            for s, q in zip(batch.state, worker[3:4][0] if batch.state else (), strict=True):
                torch.testing.assert_close(s[i], q, rtol=1e-5, atol=1e-5)
    assert batch.step_count == steps


def script_run(module, args, updates: int) -> tuple[list, list]:
    """The script's own one-worker loop (module.worker) with these Args, in process: the actions
    of each update and theta after it."""
    seed_everything(args.seed)  # as a3c_runtime.train builds the run's network
    shared = shared_for(module, args)
    actions, params = [], []
    loss, optimizer_step = module.a3c_loss, shared.optimizer.step

    def recorded_loss(log_probs, taken, *rest):
        actions.append(taken.clone())
        return loss(log_probs, taken, *rest)

    def recorded_step(grads, lr):
        optimizer_step(grads, lr)
        params.append([p.detach().clone() for p in shared.params])

    shared.optimizer.step = recorded_step
    module.a3c_loss = recorded_loss
    try:
        module.worker(0, shared, args)
    finally:
        module.a3c_loss = loss
    assert len(actions) == updates
    return actions, params


@pytest.mark.parametrize(
    ("name", "flags", "updates"),
    [
        pytest.param("a3c_ff", BATCH_FLAGS[0], UPDATES, marks=pytest.mark.slow),
        # LSTM over two episodes (rollouts of 7, 7, 1): its state carried and zeroed as the
        # script's worker carries and zeroes it, which the per-update test, handing the batch's
        # state to the script, cannot see
        ("a3c_lstm", {"t_max": 7}, 6),
    ],
)
def test_run_i_of_a_batch_runs_as_the_scripts_one_worker_run(name, flags, updates):
    """Free-running: each run of a batch starts as the script's own one-worker run with its seed
    and flags (the same initial network, env and generator) and takes its actions for 50
    updates (LSTM: 6), its parameters close to the script's. (Float rounding grows over the
    updates: a ReLU unit near 0 flips one way in one run and the other in the other, a chaos of
    the unscaled 0..255 Catch frames that the per-update test above is free of; at these
    learning rates the two stay within 1e-3.)"""
    module = load_script(name)
    steps = steps_of(updates, flags["t_max"])
    seeds_and_rates = [(1, 7e-4), (2001, 1e-4)]
    runs_args = run_args(module, flags, steps, seeds_and_rates)
    expected = [script_run(module, args, updates) for args in runs_args]
    batch = BatchedA3C(module, [BatchedRun(args) for args in runs_args], "cpu")
    for update in range(updates):
        batch.update()
        for i, (actions, params) in enumerate(expected):
            np.testing.assert_array_equal(batch.last_actions[i].numpy(), actions[update].numpy())
            for p, q in zip(batch.params, params[update], strict=True):
                torch.testing.assert_close(p[i], q, rtol=0, atol=1e-3)
    assert batch.step_count == steps


# --- The sweep's --backend batched ------------------------------------------------------------

FF = str(ROOT / "agents" / "a3c_ff.py")
TINY_RUN = ["--eval-interval", "30", "--eval-episodes", "3", "--t-max", "5"]


def batched_sweep_argv(out, *extra, runs: int = 2, steps: int = 60) -> list[str]:
    return [
        FF,
        "--out",
        str(out),
        "--runs",
        str(runs),
        "--total-timesteps",
        str(steps),
        "--backend",
        "batched",
        "--sample",
        "learning-rate=loguniform:1e-4:1e-2",
        *extra,
    ]


def batched_sweep(out, *extra, runs: int = 2, steps: int = 60):
    return run_main(sweep.main, batched_sweep_argv(out, *extra, runs=runs, steps=steps))


@pytest.mark.parametrize(
    ("extra", "says"),
    [
        (["--", "--num-workers", "2"], "cannot batch --num-workers 2"),
        # K = 4 envs per worker would run as K = 1 (issue 103, 5a)
        (["--", "--envs-per-worker", "4"], "cannot batch --envs-per-worker 4: it needs 1"),
        (["--", "--optimizer", "adam"], "cannot batch --optimizer adam"),
        (["--", "--precision", "tf32"], "--precision tf32 is a GPU's: it needs --device cuda"),
        (["--sample", "activation=choice:relu,elu"], "differ in --activation"),
        (["--sample", "gamma=uniform:0.9:0.99"], "differ in --gamma"),
        (["--", "--t-max", "0"], "--t-max must be >= 1"),
        (["--device", "tpu"], "--device must be cpu or cuda"),
        # a value the script's parser refuses: tyro's message, not its box's rules
        (
            ["--", "--activation", "tanh"],
            "): invalid choice 'tanh' for argument '--activation'. Expected one of "
            "('relu', 'elu'); nothing was run",
        ),
        (
            ["--", "--t-max", "x"],
            "): Error parsing --t-max: invalid literal for int() with base 10: 'x'",
        ),
    ],
)
def test_what_the_batched_backend_cannot_batch_is_refused_in_one_line(tmp_path, extra, says):
    result = batched_sweep(tmp_path / "out", *extra, runs=3)
    assert result.returncode == 2, result.stderr
    assert says in result.stderr and len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert not (tmp_path / "out").exists()  # nothing created


def test_another_script_and_a_device_without_batched_are_refused(tmp_path):
    growth = str(ROOT / "agents" / "future_work" / "a3c_lpq_growth.py")
    result = run_main(sweep.main, [growth, "--out", str(tmp_path / "a"), "--backend", "batched"])
    assert (
        result.returncode == 2
        and "a3c_ff.py, a3c_lstm.py, a3c_lws.py, a3c_ss.py, a3c_ww.py, a3c_lpq.py, a3c_glpq.py, "
        "not a3c_lpq_growth.py"
        in result.stderr
    )
    glpq = str(ROOT / "agents" / "a3c_glpq.py")
    argv = [glpq, "--out", str(tmp_path / "c"), "--backend", "batched", "--", "--temperature"]
    result = run_main(sweep.main, [*argv, "trainable"])
    assert result.returncode == 2 and "cannot batch --temperature trainable" in result.stderr
    assert not (tmp_path / "c").exists()
    result = run_main(sweep.main, [FF, "--out", str(tmp_path / "b"), "--device", "cuda"])
    assert result.returncode == 2 and "--device needs --backend batched" in result.stderr
    assert not (tmp_path / "a").exists() and not (tmp_path / "b").exists()


def test_a_network_that_does_not_run_under_vmap_is_refused_in_one_line(monkeypatch):
    """The probe before a batched sweep: a network whose forward branches on its data (here
    FF's, skipping its work on blank frames), which vmap cannot batch; the refusal names the
    script and the reason."""
    module = load_script("a3c_ff")

    class Branching(module.ActorCritic):
        def forward(self, obs):
            if obs.float().sum() == 0:
                return torch.zeros(len(obs), 3), torch.zeros(len(obs))
            return super().forward(obs)

    monkeypatch.setattr(module, "AGENT", dataclasses.replace(module.AGENT, network=Branching))
    args = [tiny_args(module, seed=seed, learning_rate=lr) for seed, lr in RUN_FLAGS]
    with pytest.raises(
        RunUsageError,
        match=r"cannot batch a3c_ff.py with these flags: its network does not run under vmap "
        r"\(vmap: It looks like you're attempting to use a Tensor in some data-dependent",
    ):
        probe(module, args)


def test_a_batched_sweep_writes_what_the_process_backend_writes(tmp_path):
    """results.csv with a scored row per run, and in each run's folder evaluations.csv (step 0's
    row the same as the script's own evaluator gives its initial network), a sealed checkpoint
    that the script loads (at T_max, with the worker's state) and stdout.log's closing line."""
    out = tmp_path / "out"
    result = batched_sweep(out, "--", *TINY_RUN)
    assert result.returncode == 0, result.stderr
    with open(out / "results.csv") as f:
        table = list(csv.DictReader(f))
    assert [row["run_id"] for row in table] == ["run-0000", "run-0001"]
    assert all(row["status"] == "ok" and row["final_step"] == "60" for row in table)
    module = load_script("a3c_ff")
    for row in table:
        run_dir = out / "runs" / row["run_id"]
        rows = read_evaluations(run_dir)
        assert [int(r["global_step"]) for r in rows] == [0, 30, 60]
        assert float(row["score"]) == pytest.approx(
            np.mean([float(r["mean_return"]) for r in rows[1:]])
        )
        checkpoint = load_checkpoint(str(run_dir / "checkpoint.pt"), module.AGENT)
        assert checkpoint.global_step == 60 and checkpoint.args["seed"] == int(row["seed"])
        assert set(checkpoint.workers) == {0}
        # step 0: the run's initial network (seeded by --seed) and its evaluation seeds
        args = tiny_args(module, seed=int(row["seed"]), eval_episodes=3, total_timesteps=60)
        seed_everything(args.seed)
        network = module.AGENT.build_network(3, args)
        scores = evaluate_network(network, make_eval_envs(module.AGENT, args, None), 0, args)
        assert float(rows[0]["mean_return"]) == np.mean(scores["scores"])
        # (after the progress lines of a run that lasted more than --log-interval seconds)
        assert (run_dir / "stdout.log").read_text().splitlines()[-1].startswith("done: final eval")


@pytest.mark.parametrize(
    ("name", "flags", "stop_step"),
    [("a3c_ff", {}, 20), ("a3c_lws", {"lws_trainable": False}, 20), ("a3c_lstm", {"t_max": 7}, 22)],
)
def test_a_stopped_batch_resumes_to_the_run_it_would_have_been(tmp_path, name, flags, stop_step):
    """Stopped after 4 updates (Ctrl-C), every run is checkpointed there (step 20, between two
    marks); resumed, the runs end with the evaluations and weights of a batch never stopped.
    (LWS with fixed centroids: each run's own, drawn from its seed, kept in its checkpoint.
    LSTM: stopped at step 22, in the middle of an episode, its carried state in the
    checkpoint.)"""
    module = load_script(name)

    def runs(folder):
        return [
            BatchedRun(
                tiny_args(
                    module,
                    seed=seed,
                    learning_rate=lr,
                    total_timesteps=30,
                    eval_interval=15,
                    eval_episodes=3,
                    run_dir=str(folder / f"run-{i}"),
                    **{"t_max": 5, **flags},
                )
            )
            for i, (seed, lr) in enumerate(RUN_FLAGS)
        ]

    whole = train_batched(module, runs(tmp_path / "whole"))
    assert [o["outcome"] for o in whole] == ["done", "done"]
    asked = []

    def after_4_updates() -> str | None:
        asked.append(True)
        return "SIGINT" if len(asked) > 4 else None

    stopped = train_batched(module, runs(tmp_path / "cut"), should_stop=after_4_updates)
    assert [o["outcome"] for o in stopped] == ["stopped by SIGINT", "stopped by SIGINT"]
    resumed = runs(tmp_path / "cut")
    for run in resumed:
        run.checkpoint = resumable_checkpoint(module.AGENT, Path(run.args.run_dir))
        assert run.checkpoint.global_step == stop_step
    assert [o["outcome"] for o in train_batched(module, resumed)] == ["done", "done"]
    for i in range(2):
        a, b = tmp_path / "whole" / f"run-{i}", tmp_path / "cut" / f"run-{i}"
        returns = [[r["mean_return"] for r in read_evaluations(run)] for run in (a, b)]
        assert returns[0] == returns[1] and len(returns[0]) == 3
        model_a = load_checkpoint(str(a / "checkpoint.pt"), module.AGENT).model
        model_b = load_checkpoint(str(b / "checkpoint.pt"), module.AGENT).model
        for key in model_a:
            torch.testing.assert_close(model_a[key], model_b[key], rtol=0, atol=0)
        own = module.AGENT.build_network(3, resumed[i].args).state_dict()
        assert model_a.keys() == own.keys()  # (LWS: the run's fixed centroids, as it drew them)
        for key in own:
            if not own[key].requires_grad and key.endswith("centroids"):
                torch.testing.assert_close(model_a[key], own[key], rtol=0, atol=0)


@pytest.mark.parametrize("name", ["a3c_ff", "a3c_lstm"])
def test_each_runs_evaluation_is_the_runtimes_evaluation_of_its_network(name):
    """After 3 updates, the batch's evaluation of each run scores every episode as the
    runtime's evaluate_network scores that run's network, with that run's flags (its seed's
    episodes and draws), sampled from pi in one run and greedy (--eval-greedy) in the other.
    (LSTM: a state per episode.)"""
    module = load_script(name)
    runs_args = [
        tiny_args(
            module,
            seed=seed,
            learning_rate=lr,
            eval_episodes=12,
            eval_greedy=greedy,
            total_timesteps=1000,
            t_max=5,
        )
        for (seed, lr), greedy in zip(RUN_FLAGS, (False, True), strict=True)
    ]
    batch = BatchedA3C(module, [BatchedRun(args) for args in runs_args], "cpu")
    for _ in range(3):
        batch.update()
    results = [batch.evaluate(i) for i in range(2)]
    for i, (args, result) in enumerate(zip(runs_args, results, strict=True)):
        network = module.AGENT.build_network(3, args)
        network.load_state_dict(batch.network(i))
        envs = make_eval_envs(module.AGENT, args, None)
        expected = evaluate_network(network, envs, 15, args)
        assert result["global_step"] == 15 and result["scores"] == expected["scores"]
    assert sum(map(sum, (r["scores"] for r in results))) > 0  # some episodes are caught


@pytest.mark.parametrize(
    ("precision", "acting", "learning"),
    [("fp32", False, False), ("bf16", True, True), ("bf16-learn", False, True)],
)
def test_each_batched_forward_pass_runs_in_its_precision(precision, acting, learning):
    """--precision opts a batch into bf16 as it does a worker (tests/test_precision.py): the
    acting passes under bf16 autocast for bf16, the learning passes (the loss's forward, and
    the bootstrap value, which the worker takes from its learning pass) for bf16 and
    bf16-learn; fp32 neither. The parameters and optimizer statistics stay float32."""
    module = load_script("a3c_ff")
    runs_args = run_args(module, {"t_max": 5}, steps_of(3, 5), RUN_FLAGS)
    runs_args = [dataclasses.replace(args, precision=precision) for args in runs_args]
    batch = BatchedA3C(module, [BatchedRun(args) for args in runs_args], "cpu")
    calls, phase = [], ["act"]
    act, loss, forward = batch.act, batch.loss, module.ActorCritic.forward

    def recording_act(frames, state=(), precision=None):
        phase[0] = "act" if precision is None else "learn"  # (the bootstrap's: learning's)
        return act(frames, state, precision)

    def recording_loss(*args):
        phase[0] = "learn"
        return loss(*args)

    def recording_forward(self, *inputs, **kwargs):
        calls.append((phase[0], torch.is_autocast_enabled("cpu")))
        return forward(self, *inputs, **kwargs)

    batch.act, batch.loss = recording_act, recording_loss
    try:
        module.ActorCritic.forward = recording_forward
        for _ in range(3):  # (rollouts of 5, each bootstrapped: a 15-step episode ends at 3)
            batch.update()
    finally:
        module.ActorCritic.forward = forward
    assert {on for where, on in calls if where == "act"} == {acting}, calls
    assert {on for where, on in calls if where == "learn"} == {learning}, calls
    assert all(p.dtype == torch.float32 for p in batch.params + batch.optimizer.square_avg)


def test_tf32_is_a_gpus_and_refused_elsewhere_in_one_line(monkeypatch, capsys):
    """--precision tf32 (TF32 matrix multiplies on a GPU) is the batched backend's on cuda:
    a batch on the CPU and a script's own run (its workers on the CPU) refuse it in one line,
    exit 2, before anything is created."""
    module = load_script("a3c_ff")
    args = run_args(module, {"t_max": 5}, 100, RUN_FLAGS[:1])[0]
    with pytest.raises(RunUsageError, match="tf32 is a GPU's: it needs --device cuda"):
        BatchedA3C(module, [BatchedRun(dataclasses.replace(args, precision="tf32"))], "cpu")
    code, err = main_exit(module, ["--precision", "tf32", "--run-dir", "never"], monkeypatch,
                          capsys)  # fmt: skip
    assert code == 2 and "the sweep's batched backend takes it" in err, err
    assert len(err.strip().splitlines()) == 1 and not Path("never").exists()


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_tf32_on_a_gpu_turns_on_tf32_and_fp32_turns_it_off():
    runtime_batched.set_up_device("cuda", "tf32")
    assert torch.backends.cuda.matmul.allow_tf32 and torch.backends.cudnn.allow_tf32
    runtime_batched.set_up_device("cuda", "fp32")
    assert not (torch.backends.cuda.matmul.allow_tf32 or torch.backends.cudnn.allow_tf32)
    assert torch.backends.cudnn.deterministic and not torch.backends.cudnn.benchmark


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
@pytest.mark.parametrize("conv_form", ["matmul", "grouped"])
@pytest.mark.parametrize(("name", "t_max"), [("a3c_ff", 5), ("a3c_lstm", 7), ("a3c_lws", 5)])
def test_each_update_on_a_gpu_is_the_scripts_update_from_its_state(
    monkeypatch, name, t_max, conv_form
):
    """The per-update test on a CUDA device (the lent GPU machine's check; CI has none): the
    batch on the GPU, its convolutions either way, takes the script's actions, its theta close
    to the script's CPU update (LSTM: and its carried state)."""
    module = load_script(name)
    runs_args = run_args(module, {"t_max": t_max}, steps_of(20, t_max), RUN_FLAGS)
    batch = BatchedA3C(module, [BatchedRun(args) for args in runs_args], "cuda", conv_form)
    torch.backends.cudnn.allow_tf32 = torch.backends.cuda.matmul.allow_tf32 = False
    shareds = [one_update_shared(module, args, monkeypatch) for args in runs_args]
    on_cpu = SimpleNamespace(
        params=[p.cpu() for p in batch.params],
        optimizer=SimpleNamespace(square_avg=[s.cpu() for s in batch.optimizer.square_avg]),
    )
    for _ in range(20):
        on_cpu.params = [p.cpu() for p in batch.params]
        on_cpu.optimizer.square_avg = [s.cpu() for s in batch.optimizer.square_avg]
        on_cpu.step_count, on_cpu.uniforms = batch.step_count, batch.uniforms
        on_cpu.state = tuple(s.cpu() for s in batch.state)
        on_cpu.envs = CpuView(batch.envs)
        expected = [script_update(module, shared, on_cpu, i) for i, shared in enumerate(shareds)]
        batch.update()
        for i, (actions, params, _, worker) in enumerate(expected):
            np.testing.assert_array_equal(batch.last_actions[i].cpu().numpy(), actions.numpy())
            for p, q in zip(batch.params, params, strict=True):
                torch.testing.assert_close(p[i].cpu(), q, rtol=1e-4, atol=1e-4)
            for s, q in zip(batch.state, worker[3:4][0] if batch.state else (), strict=True):
                torch.testing.assert_close(s[i].cpu(), q, rtol=1e-4, atol=1e-4)


class CpuView:
    """A TorchCatchVectorEnv on a GPU as script_update reads it: its games' NumPy states and
    stacked frames on the host."""

    def __init__(self, envs):
        self.envs, self.stack = envs, envs.stack.cpu()

    def numpy_state(self, env):
        return self.envs.numpy_state(env)


def test_thesis_figures_pass_the_batched_backend_to_their_sweeps():
    """thesis_figures --backend batched --device cuda: each line's sweep gets both; --device
    without it is refused in one line."""
    from a3c_tools import thesis_figures

    result = run_main(
        thesis_figures.main, ["fig6.3", "--dry-run", "--backend", "batched", "--device", "cuda"]
    )
    assert result.returncode == 0, result.stderr
    sweeps = [
        line for line in result.stdout.splitlines() if line.startswith("python -m a3c_tools.sweep")
    ]
    assert sweeps and all(" --backend batched --device cuda -- " in line for line in sweeps)
    result = run_main(thesis_figures.main, ["fig6.3", "--dry-run", "--device", "cuda"])
    assert result.returncode == 2 and "--device needs --backend batched" in result.stderr


def test_a_full_disk_stops_the_batch_with_its_checkpoints_whole(tmp_path, monkeypatch):
    """The second checkpoint's write fails (ENOSPC, as a full disk fails it): the sweep ends with
    exit 1 and one line saying how to go on, the first checkpoints intact; started again, it
    resumes them from step 15 and finishes every run."""
    save, saves = runtime_batched.save_checkpoint, []

    def full_disk_at_the_second_mark(path, *rest):
        saves.append(path)
        if len(saves) > 2:  # two runs: their checkpoints at step 15 are written, then none
            raise WriteFailed(path, OSError(errno.ENOSPC, "No space left on device"))
        save(path, *rest)

    monkeypatch.setattr(runtime_batched, "save_checkpoint", full_disk_at_the_second_mark)
    out = tmp_path / "out"
    tiny = ["--eval-interval", "15", "--eval-episodes", "2", "--t-max", "5"]
    result = batched_sweep(out, "--", *tiny, steps=30)
    assert result.returncode == 1
    assert "No space left on device" in result.stderr and "start the sweep again" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1 and not (out / "results.csv").exists()
    module = load_script("a3c_ff")
    for run in ("run-0000", "run-0001"):
        checkpoint = load_checkpoint(str(out / "runs" / run / "checkpoint.pt"), module.AGENT)
        assert checkpoint.global_step == 15
    monkeypatch.setattr(runtime_batched, "save_checkpoint", save)
    result = batched_sweep(out, "--", *tiny, steps=30)
    assert result.returncode == 0, result.stderr
    assert "resuming at step 15" in result.stdout
    for run in ("run-0000", "run-0001"):
        assert [int(r["global_step"]) for r in read_evaluations(out / "runs" / run)] == [0, 15, 30]


# --- Issue 101: the run lock, RunLog's scalars, the stopping signal, cuDNN, the lockstep -------


def hold_run_folder(path, ready, release) -> None:
    """Another process's hold on a run folder, as a run resumed by hand there holds it."""
    from a3c_runtime.run_folder import RunFolder

    folder = RunFolder(path)
    ready.set()
    release.wait(60)
    folder.close()


def stop_after(updates: int):
    """A should_stop that stops a batch after `updates` updates, as Ctrl-C stops it."""
    asked = []

    def should_stop() -> str | None:
        asked.append(True)
        return "SIGINT" if len(asked) > updates else None

    return should_stop


def tiny_runs(module, folder: Path, **flags) -> list:
    """The two runs of RUN_FLAGS, 30 steps in rollouts of 5, evaluated every 15, in folder."""
    flags = {"total_timesteps": 30, "t_max": 5, "eval_interval": 15, "eval_episodes": 2, **flags}
    folders = [str(folder / f"run-{i}") for i in range(len(RUN_FLAGS))]
    return [
        BatchedRun(tiny_args(module, seed=seed, learning_rate=lr, run_dir=run_dir, **flags))
        for (seed, lr), run_dir in zip(RUN_FLAGS, folders, strict=True)
    ]


def read_table(out: Path) -> list[dict]:
    with open(out / "results.csv") as f:
        return list(csv.DictReader(f))


def test_a_batched_sweep_leaves_a_run_in_use_elsewhere_alone_and_runs_it_once_free(tmp_path):
    """A run of the sweep being resumed by hand (its folder locked by the runtime's lock in
    another process): the batched sweep neither reads nor touches its folder, records no row
    for it, says "in use" and exits 3, as the process backend's sweep does; started again once
    it is free, it runs it."""
    out = tmp_path / "out"
    busy = out / "runs" / "run-0001"
    busy.mkdir(parents=True)
    (busy / "stdout.log").write_text("run run-0001 -> resumed by hand\n")
    (busy / "evaluations.csv").write_text(
        "global_step,wall_time_s,mean_return,std_return,episodes\n0,1.0,0.0,0.0,3\n"
    )
    before = {path.name: path.read_bytes() for path in busy.iterdir()}
    ready, release = FORK.Event(), FORK.Event()
    holder = FORK.Process(target=hold_run_folder, args=(busy, ready, release))
    holder.start()
    try:
        assert ready.wait(30)
        result = batched_sweep(out, "--", *TINY_RUN)
        assert result.returncode == sweep.IN_USE_EXIT == 3, result.stdout + result.stderr
        assert f"run-0001 in use: {busy} is held by process {holder.pid}" in result.stdout
        assert "not done: 1 ok, 0 failed, 1 in use elsewhere (run-0001)" in result.stdout
        assert [(r["run_id"], r["status"]) for r in read_table(out)] == [("run-0000", "ok")]
        after = {path.name: path.read_bytes() for path in busy.iterdir()}
        assert after.pop("run.lock") == f"{holder.pid}\n".encode()  # the holder's
        assert after == before  # untouched: no file removed, changed or added
    finally:
        release.set()
        holder.join(30)
    result = batched_sweep(out, "--", *TINY_RUN)
    assert result.returncode == 0, result.stdout + result.stderr
    assert [(r["run_id"], r["status"]) for r in read_table(out)] == [
        ("run-0000", "ok"),
        ("run-0001", "ok"),
    ]
    assert [int(r["global_step"]) for r in read_evaluations(busy)] == [0, 30, 60]
    assert not (busy / "run.lock").exists()  # given back


def test_each_batched_run_writes_the_runtimes_tensorboard_scalars(tmp_path):
    """Each run's folder gets what the runtime's RunLog writes for a run: TensorBoard's eval/
    scalars at the evaluations.csv rows' steps and values, the charts/ and losses/ scalars at
    each progress mark (here every update) with the run's own learning rate, and the progress
    lines in its stdout.log, before its closing line."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    module = load_script("a3c_ff")
    runs = tiny_runs(module, tmp_path, log_interval=1e-9)
    assert [o["outcome"] for o in train_batched(module, runs)] == ["done", "done"]
    losses = []
    for run in runs:
        run_dir = Path(run.args.run_dir)
        events = EventAccumulator(str(run_dir))
        events.Reload()
        tags = set(events.Tags()["scalars"])
        expected = {"eval/mean_return", "eval/std_return", "charts/SPS", "charts/learning_rate",
                    "charts/episodic_return", "charts/episodic_length", "losses/policy_loss",
                    "losses/value_loss", "losses/entropy", "losses/grad_norm"}  # fmt: skip
        assert expected <= tags, tags
        rows = read_evaluations(run_dir)
        evals = [(e.step, e.value) for e in events.Scalars("eval/mean_return")]
        assert evals == [(int(r["global_step"]), pytest.approx(float(r["mean_return"])))
                         for r in rows]  # fmt: skip
        rates = events.Scalars("charts/learning_rate")
        assert [e.step for e in rates] == list(range(5, 31, 5))
        for e in rates:
            assert e.value == pytest.approx(run.args.learning_rate * (1 - e.step / 30))
        lengths = [e.value for e in events.Scalars("charts/episodic_length")]
        assert lengths == [15.0, 15.0]  # Catch's episodes, ended at steps 15 and 30
        losses.append([e.value for e in events.Scalars("losses/value_loss")])
        lines = (run_dir / "stdout.log").read_text().splitlines()
        assert lines[0].startswith("step 5/30 (16.7%) | SPS") and len(lines) == 7
        assert lines[-1].startswith("done: final eval")
    assert losses[0] != losses[1]  # each run's own (their seeds and learning rates differ)


def test_a_batch_stopped_by_sigterm_names_it_and_resumes_from_its_checkpoints(
    tmp_path, monkeypatch
):
    """SIGTERM to a batched sweep after two updates: each run's stdout.log says "stopped by
    SIGTERM" (not SIGINT), the sweep says the stopped runs resume from their checkpoints, and
    started again it resumes them from step 10."""
    update, updates = BatchedA3C.update, []

    def update_then_sigterm(self):
        handler = signal.getsignal(signal.SIGTERM)
        if isinstance(getattr(handler, "__self__", None), sweep.StopRequests):  # (not the probe)
            updates.append(self.step_count)
            if len(updates) == 2:  # the sweep's handler runs before this update returns
                os.kill(os.getpid(), signal.SIGTERM)
        return update(self)

    monkeypatch.setattr(BatchedA3C, "update", update_then_sigterm)
    out = tmp_path / "out"
    result = batched_sweep(out, "--", *TINY_RUN)
    assert result.returncode == 130, result.stdout + result.stderr
    assert ("SIGTERM: stopping the running runs (started again, the sweep resumes them from "
            "their checkpoints)") in result.stdout  # fmt: skip
    assert "rerun" not in result.stdout
    module = load_script("a3c_ff")
    for run in ("run-0000", "run-0001"):
        log = (out / "runs" / run / "stdout.log").read_text().splitlines()
        assert log[-1].startswith("stopped by SIGTERM: last eval"), log
        checkpoint = load_checkpoint(str(out / "runs" / run / "checkpoint.pt"), module.AGENT)
        assert checkpoint.global_step == 10
    monkeypatch.setattr(BatchedA3C, "update", update)
    result = batched_sweep(out, "--", *TINY_RUN)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "batched: 2 runs on cpu, resuming at step 10" in result.stdout
    assert [r["status"] for r in read_table(out)] == ["ok", "ok"]


def test_set_up_device_cuda_makes_cudnn_deterministic():
    """On CUDA: no TF32, and cuDNN's deterministic algorithms, none chosen by benchmarking
    (the flags only: they are set the same on a machine without a GPU)."""
    cudnn, matmul = torch.backends.cudnn, torch.backends.cuda.matmul
    saved = (cudnn.deterministic, cudnn.benchmark, cudnn.allow_tf32, matmul.allow_tf32)
    try:
        cudnn.deterministic, cudnn.benchmark = False, True
        cudnn.allow_tf32 = matmul.allow_tf32 = True
        runtime_batched.set_up_device("cuda")
        assert cudnn.deterministic and not cudnn.benchmark
        assert not cudnn.allow_tf32 and not matmul.allow_tf32
    finally:
        cudnn.deterministic, cudnn.benchmark, cudnn.allow_tf32, matmul.allow_tf32 = saved


def test_runs_at_one_step_but_other_steps_of_their_episodes_are_batched_apart(tmp_path):
    """A run resumed by hand with two workers for a while, then one, holds a checkpoint whose
    global step counts the other worker's steps: at step 20 its game is 10 steps into an
    episode, another run's at step 20 is 5 steps in. Their episodes would end at different
    steps of one batch (a RuntimeError mid-run); the sweep batches them apart, and each run
    finishes. A batch of such runs built by hand is refused before anything runs."""
    out = tmp_path / "out"
    sweep_args, fixed = sweep.parse_args(batched_sweep_argv(out, "--", *TINY_RUN))
    planned = sweep.plan_runs(sweep.configuration(sweep_args, fixed), 2)
    module = load_script("a3c_ff")
    runs = []
    for run, updates in zip(planned, (4, 2), strict=True):
        run_dir = out / "runs" / run.run_id
        args = resolve_run_args(parsed_flags(module.Args, run.command(FF, run_dir)[1:]))
        train_batched(module, [BatchedRun(args)], should_stop=stop_after(updates))
        runs.append(args)
    path = out / "runs" / "run-0001" / "checkpoint.pt"
    raw = read_checkpoint(path)
    assert raw["global_step"] == 10
    raw["global_step"] = 20  # (and the other worker's 10 steps)
    rewrite_checkpoint(path, raw)
    resumed = [BatchedRun(args, resumable_checkpoint(module.AGENT, Path(args.run_dir)))
               for args in runs]  # fmt: skip
    assert [run.checkpoint.global_step for run in resumed] == [20, 20]
    with pytest.raises(ValueError, match=r"same step of their episodes .* rows \[9, 14\]"):
        BatchedA3C(module, resumed, "cpu")
    result = batched_sweep(out, "--", *TINY_RUN)
    assert result.returncode == 0, result.stdout + result.stderr
    assert result.stdout.count("batched: 1 runs on cpu, resuming at step 20") == 2
    assert [(r["status"], r["final_step"]) for r in read_table(out)] == [("ok", "60")] * 2


def test_runs_resumed_in_one_batch_keep_their_own_wall_times(tmp_path):
    """Two runs resumed in one batch from checkpoints with their own wall times (1,000 s and
    5,000 s): each run's clock goes on from its own, in its evaluations.csv rows, its
    checkpoint and its outcome (issue 103, 5b)."""
    module = load_script("a3c_ff")
    train_batched(module, tiny_runs(module, tmp_path), should_stop=stop_after(2))
    resumed, offsets = tiny_runs(module, tmp_path), (1000.0, 5000.0)
    for run, offset in zip(resumed, offsets, strict=True):
        checkpoint = resumable_checkpoint(module.AGENT, Path(run.args.run_dir))
        assert checkpoint.global_step == 10
        run.checkpoint = dataclasses.replace(checkpoint, wall_time=offset)
    outcomes = train_batched(module, resumed)
    for run, offset, outcome in zip(resumed, offsets, outcomes, strict=True):
        run_dir = Path(run.args.run_dir)
        own_clock = pytest.approx(offset, abs=500)  # (the test's seconds on top)
        assert outcome["outcome"] == "done" and outcome["wall_time_s"] == own_clock
        rows = [r for r in read_evaluations(run_dir) if int(r["global_step"]) > 10]
        assert [float(r["wall_time_s"]) for r in rows] == [own_clock, own_clock]
        assert load_checkpoint(str(run_dir / "checkpoint.pt"), module.AGENT).wall_time == own_clock


def test_a_batch_may_hold_its_files_open_past_a_low_soft_limit():
    """allow_open_files raises the soft limit of open files to what a batch holds (never above
    the hard limit, never lowering it)."""
    resource = pytest.importorskip("resource")
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    low = 256
    expected = 600 if hard == resource.RLIM_INFINITY else min(600, hard)
    try:
        resource.setrlimit(resource.RLIMIT_NOFILE, (low, hard))
        runtime_batched.allow_open_files(600)
        assert resource.getrlimit(resource.RLIMIT_NOFILE) == (expected, hard)
        runtime_batched.allow_open_files(100)
        assert resource.getrlimit(resource.RLIMIT_NOFILE) == (expected, hard)
    finally:
        resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


# --- The batched pieces against the runtime's and the script's, run by run ---------------------


@pytest.mark.parametrize("mode", ["norm", "value", "global-norm", "none"])
def test_stacked_clipping_is_the_runtimes_clipping_of_each_run(mode):
    """Three runs' gradients, one far above the bound, one below, one with a single tensor
    above it: clip_stacked gives each run what clip_gradients (a stack of one) gives it alone,
    and its global norm: no run's clipping depends on another's."""
    from a3c_runtime import clip_gradients, clip_stacked

    generator = torch.Generator().manual_seed(0)
    shapes = [(4, 3), (5,), (2, 2, 2)]
    scales = [[30.0, 30.0, 30.0], [0.1, 0.1, 0.1], [0.1, 20.0, 0.1]]
    per_run = [[torch.randn(s, generator=generator) * k for s, k in zip(shapes, run, strict=True)]
               for run in scales]  # fmt: skip
    stacked = [torch.stack([run[j] for run in per_run]) for j in range(len(shapes))]
    norms = clip_stacked(stacked, mode, 5.0)
    for i, run in enumerate(per_run):
        assert norms[i].item() == pytest.approx(clip_gradients(run, mode, 5.0), rel=1e-6)
        for j, g in enumerate(run):
            torch.testing.assert_close(stacked[j][i], g, rtol=1e-6, atol=1e-7)


def test_stacked_rmsprop_is_the_runtimes_rmsprop_of_each_run_at_its_learning_rate():
    from a3c_runtime import RMSprop

    generator = torch.Generator().manual_seed(1)
    params = [torch.randn(3, 4, 2, generator=generator), torch.randn(3, 5, generator=generator)]
    stacked = RMSprop([p.clone() for p in params], 0.9, 0.1, 0.5, shared=False)
    singles = [RMSprop([p[i].clone() for p in params], 0.9, 0.1, 0.5) for i in range(3)]
    lrs = [1e-3, 1e-2, 0.5]
    for _ in range(3):
        grads = [torch.randn(p.shape, generator=generator) * 10 for p in params]
        stacked.step(grads, torch.tensor(lrs))
        for i, single in enumerate(singles):
            single.step([g[i] for g in grads], lrs[i])
    for i, single in enumerate(singles):
        for p, q, s, t in zip(stacked.params, single.params, stacked.square_avg,
                              single.square_avg, strict=True):  # fmt: skip
            torch.testing.assert_close(p[i], q, rtol=1e-6, atol=1e-7)
            torch.testing.assert_close(s[i], t, rtol=1e-6, atol=1e-7)


@settings(max_examples=50, deadline=None)
@given(
    logits=st.lists(st.tuples(*[st.floats(-20, 20)] * 3), min_size=1, max_size=8),
    uniforms=st.lists(st.floats(0, 1, exclude_max=True), min_size=8, max_size=8),
)
@example(logits=[(0.0, -2.00001, -16.75)], uniforms=[0.9999999999999999] + [0.0] * 7)
def test_the_batchs_action_draws_are_the_workers(logits, uniforms):
    """The runtime's one sample_actions, which the worker calls on NumPy arrays and the batched
    backend on tensors, draws the same actions from the same probabilities and uniforms; and
    the worker's is that one (no copy of its own)."""
    from a3c_runtime import sample_actions

    assert load_script("a3c_ff").sample_actions is sample_actions
    log_probs = torch.log_softmax(torch.tensor(logits, dtype=torch.float32), dim=1)
    u = np.array(uniforms[: len(logits)])
    expected = sample_actions(log_probs.exp().numpy(), u)
    got = sample_actions(log_probs.exp(), torch.from_numpy(u))
    np.testing.assert_array_equal(got.numpy(), expected)


@settings(max_examples=200, deadline=None)
@given(
    logits=st.integers(2, 18).flatmap(
        lambda a: st.lists(
            st.lists(st.floats(-20, 20), min_size=a, max_size=a), min_size=1, max_size=16
        )  # fmt: skip
    ),
    at=st.integers(0, 17),
)
@example(logits=[[0.0, -2.00001, -16.75]], at=1)  # hypothesis's find: torch.cumsum's last bit
def test_the_draws_are_the_same_on_tensors_at_the_cdfs_edges(logits, at):
    """Uniforms on the edges of the cumulative sums (u = cdf[k] / cdf[-1], where one bit of a
    sum flips the draw), any number of actions: the same actions from tensors as from NumPy
    arrays (torch's cumsum, which accumulates in float64, drew others)."""
    from a3c_runtime import sample_actions

    probs = torch.softmax(torch.tensor(logits, dtype=torch.float32), dim=1)
    cdf = np.cumsum(probs.numpy(), axis=1)
    k = min(at, probs.shape[1] - 1)
    u = np.nextafter(cdf[:, k].astype(np.float64) / cdf[:, -1], 0.0).clip(0, np.nextafter(1, 0))
    expected = sample_actions(probs.numpy(), u)
    np.testing.assert_array_equal(sample_actions(probs, torch.from_numpy(u)).numpy(), expected)


def test_the_lstm_scripts_cell_is_torchs_lstm_cell_and_runs_under_vmap():
    """a3c_lstm.LSTMCell (torch's formula in ops vmap batches), which the worker and the batched
    backend both step, gives nn.LSTMCell's h, c and gradients bit for bit on the CPU, and under
    vmap over stacked cells each cell's own."""
    LSTMCell = load_script("a3c_lstm").LSTMCell
    torch.manual_seed(0)
    cells = [LSTMCell(6, 4) for _ in range(3)]
    torch_cells = [torch.nn.LSTMCell(6, 4) for _ in range(3)]
    for cell, torch_cell in zip(cells, torch_cells, strict=True):
        torch_cell.load_state_dict(cell.state_dict())
    x, h, c = torch.randn(3, 5, 6), torch.randn(3, 5, 4), torch.randn(3, 5, 4)
    expected = [cell(x[k], (h[k], c[k])) for k, cell in enumerate(torch_cells)]
    for k, cell in enumerate(cells):
        got = cell(x[k], (h[k], c[k]))
        for g, want in zip(got, expected[k], strict=True):
            assert torch.equal(g, want)
        grads = torch.autograd.grad(sum(t.sum() for t in got), list(cell.parameters()))
        wanted = torch.autograd.grad(sum(t.sum() for t in expected[k]),
                                     list(torch_cells[k].parameters()))  # fmt: skip
        assert all(torch.equal(g, w) for g, w in zip(grads, wanted, strict=True))
    params, _ = torch.func.stack_module_state(cells)

    def step(weights, x, state):
        return torch.func.functional_call(cells[0], weights, (x, state))

    h_all, c_all = torch.func.vmap(step)(params, x, (h, c))
    for k in range(3):
        torch.testing.assert_close(h_all[k], expected[k][0], rtol=1e-6, atol=1e-6)
        torch.testing.assert_close(c_all[k], expected[k][1], rtol=1e-6, atol=1e-6)


def test_the_reproducing_page_states_the_backends_check_as_committed():
    """docs/reproducing.md's sentence on campaign item g1 (16 runs of A3C FF on each backend,
    paired by seed) follows the committed runs: "not in yet" until the batched line holds all
    16, then the paired difference (batched - process) and 95% t interval those runs give, and
    the plan's verdict for it: equivalent within +-0.1, different outside, else inconclusive."""
    from a3c_tools.paired import decision, interval, read_scores

    page = " ".join((ROOT / "docs" / "reproducing.md").read_text().split())
    folder = ROOT / "results" / "batched_equivalence"
    process = read_scores(folder / "process" / "results.csv")
    table = folder / "batched" / "results.csv"
    batched_scores = read_scores(table) if table.is_file() else {}
    ids = [f"run-{i:04d}" for i in range(16)]
    assert all(i in process for i in ids), "the process line holds its 16 runs"
    if not all(i in batched_scores for i in ids):
        assert "its result is not in yet" in page
        return
    d = np.array([batched_scores[i] - process[i] for i in ids])
    low, high = interval(d)
    word = decision("comparable", low, high, len(d), margin=0.1)
    verdict = {"reproduced": "equivalent", "contradicted": "different"}.get(word, word)
    assert f"{d.mean():+.3f} [{low:+.3f}, {high:+.3f}]" in page
    assert f"g1: {verdict}" in page
    assert "its result is not in yet" not in page
