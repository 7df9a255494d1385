"""Unit tests of agents/a3c_runtime.py, the run machinery every script shares: clipping, the
shared optimizers, error reporting, checkpoints, flag checks, evaluation and logging. The
machinery tests run against every script (SCRIPTS), in process; the end-to-end ones are in
tests/test_a3c_ff.py."""

import math
import multiprocessing
import sys
import warnings
from pathlib import Path
from types import SimpleNamespace

import a3c_runtime as runtime
import numpy as np
import pytest
import torch
from conftest import SCRIPTS, load_script

import catch_env  # noqa: F401  (registers Catch-v0)

FORK = multiprocessing.get_context("fork")


def test_clip_gradients_modes():
    def grads():
        return [torch.tensor([30.0, 40.0]), torch.tensor([3.0, -50.0])]

    g = grads()
    norm = runtime.clip_gradients(g, "norm", 40.0)  # per tensor: [30, 40] has norm 50 -> x0.8
    assert norm == pytest.approx(math.sqrt(50**2 + 9 + 2500))
    np.testing.assert_allclose(g[0].numpy(), [24.0, 32.0], rtol=1e-5)
    np.testing.assert_allclose(g[1].numpy(), np.array([3.0, -50.0]) * 40 / math.sqrt(2509))
    g = grads()
    runtime.clip_gradients(g, "value", 40.0)
    np.testing.assert_allclose(torch.cat(g).numpy(), [30.0, 40.0, 3.0, -40.0])
    g = grads()
    total = math.sqrt(2500 + 2509)
    runtime.clip_gradients(g, "global-norm", 25.0)
    np.testing.assert_allclose(
        torch.cat(g).numpy(), np.array([30.0, 40.0, 3.0, -50.0]) * 25 / total, rtol=1e-5
    )
    g = grads()
    runtime.clip_gradients(g, "none", 1.0)
    np.testing.assert_allclose(torch.cat(g).numpy(), [30.0, 40.0, 3.0, -50.0])


def test_shared_rmsprop_step():
    param = torch.tensor([1.0, -1.0])
    opt = runtime.SharedRMSprop([param], decay=0.99, eps=0.1)
    opt.step([torch.tensor([2.0, 0.0])], lr=0.1)
    # ms = 0.01 * g^2 = [0.04, 0]; theta -= 0.1 * g / sqrt(ms + 0.1)
    np.testing.assert_allclose(opt.square_avg[0].numpy(), [0.04, 0.0], rtol=1e-6)
    np.testing.assert_allclose(param.numpy(), [1.0 - 0.2 / math.sqrt(0.14), -1.0], rtol=1e-6)


def test_shared_rmsprop_from_tensorflows_initial_mean_square():
    """--rms-init 1 (TensorFlow's RMSPropOptimizer): with a small eps the first step stays
    about lr * g instead of 10 lr per weight."""
    param = torch.tensor([1.0, -1.0])
    opt = runtime.SharedRMSprop([param], decay=0.99, eps=1e-5, initial=1.0)
    opt.step([torch.tensor([2.0, 0.0])], lr=0.1)
    # ms = 0.99 * 1 + 0.01 * g^2 = [1.03, 0.99]; theta -= 0.1 * g / sqrt(ms + 1e-5)
    np.testing.assert_allclose(opt.square_avg[0].numpy(), [1.03, 0.99], rtol=1e-6)
    np.testing.assert_allclose(param.numpy(), [1.0 - 0.2 / math.sqrt(1.03001), -1.0], rtol=1e-6)
    zero_start = torch.tensor([1.0])
    runtime.SharedRMSprop([zero_start], decay=0.99, eps=1e-5).step([torch.tensor([2.0])], lr=0.1)
    assert zero_start.item() == pytest.approx(1.0 - 0.2 / math.sqrt(0.04001), abs=1e-6)  # 10 lr


def test_shared_adam_step():
    param = torch.tensor([1.0])
    opt = runtime.SharedAdam([param], beta1=0.9, beta2=0.99, eps=0.1)
    opt.step([torch.tensor([2.0])], lr=0.1)
    # m_hat = g, v_hat = g^2 after one step: theta -= 0.1 * 2 / sqrt(4 + 0.1)
    np.testing.assert_allclose(param.numpy(), [1.0 - 0.2 / math.sqrt(4.1)], rtol=1e-6)
    assert opt.step_count.item() == 1


def _step_in_child(opt, grad_value):
    opt.step([torch.full((3,), grad_value)], lr=0.01)


def test_shared_rmsprop_state_is_shared_between_processes():
    param = torch.zeros(3).share_memory_()
    opt = runtime.SharedRMSprop([param], decay=0.99, eps=0.1)
    for grad_value in (1.0, 2.0):  # two processes, one after the other
        child = FORK.Process(target=_step_in_child, args=(opt, grad_value))
        child.start()
        child.join(30)
        assert child.exitcode == 0
    # both children's updates are visible here: ms = 0.99 * 0.01 * 1 + 0.01 * 4
    np.testing.assert_allclose(opt.square_avg[0].numpy(), [0.0499] * 3, rtol=1e-5)
    first = 0.01 * 1 / math.sqrt(0.01 + 0.1)
    second = 0.01 * 2 / math.sqrt(0.0499 + 0.1)
    np.testing.assert_allclose(param.numpy(), [-(first + second)] * 3, rtol=1e-5)


def test_annealed_lr():
    args = SimpleNamespace(total_timesteps=1000, learning_rate=1e-3, anneal_lr=True)
    assert runtime.annealed_lr(args, 0) == pytest.approx(1e-3)
    assert runtime.annealed_lr(args, 250) == pytest.approx(7.5e-4)
    assert runtime.annealed_lr(args, 2000) == 0.0
    args.anneal_lr = False
    assert runtime.annealed_lr(args, 250) == pytest.approx(1e-3)


def test_run_process_reports_exceptions():
    errors = FORK.SimpleQueue()
    child = FORK.Process(target=runtime.run_process, args=("worker 7", errors, lambda: 1 / 0))
    child.start()
    child.join(30)
    assert child.exitcode == 1
    name, trace = errors.get()
    assert name == "worker 7" and "ZeroDivisionError" in trace


def test_defaults_and_validation():
    a3c = load_script("a3c_ff")
    catch = runtime.resolve_defaults(a3c.Args())
    assert (catch.total_timesteps, catch.eval_interval, catch.scale_obs) == (10**6, 50_000, False)
    assert catch.grad_clip == 40.0 and catch.learning_rate == 7e-4 and catch.eval_episodes == 50
    assert runtime.resolve_defaults(a3c.Args(grad_clip_mode="global-norm")).grad_clip == 25.0
    atari = runtime.resolve_defaults(a3c.Args(env="BreakoutNoFrameskip-v4"))
    assert (atari.total_timesteps, atari.eval_interval, atari.scale_obs) == (10**8, 10**6, True)
    with pytest.raises(runtime.UsageError, match="--gamma must be in"):
        runtime.resolve_defaults(a3c.Args(gamma=1.5))
    with pytest.raises(runtime.UsageError, match="unknown --env"):
        runtime.resolve_defaults(a3c.Args(env="Nope-v0"))


# ---------------------------------------------------------------------------------------------
# Every script: the machinery in process


def tiny_args(module, **flags):
    return runtime.resolve_defaults(module.Args(num_workers=1, **flags))


def shared_for(module, args, num_actions=3) -> runtime.Shared:
    return runtime.Shared(module.AGENT.build_network(num_actions, args), args, FORK)


@pytest.fixture
def one_thread():
    """A worker's torch: one thread (run_process sets it in a real run)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


@pytest.mark.parametrize("name", SCRIPTS)
def test_worker_learns_in_process_without_warnings_or_autograd_history(name, one_thread):
    module = load_script(name)
    # t_max 5 < Catch's 15-step episodes: rollouts bootstrap from V(s_last)
    args = tiny_args(module, total_timesteps=60, t_max=5)
    shared = shared_for(module, args)
    before = [p.detach().clone() for p in shared.params]
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # normal runs print no warnings
        module.worker(0, shared, args)
    assert 60 <= shared.global_step() < 60 + args.t_max
    assert shared.stats[0, 3] >= 60 // 5  # updates
    # every parameter learns, except those that provably get no gradient:
    # - a3c_ss.py: the second convolution's bias (torso.2.bias) adds a constant to each map, which
    #   the spatial softmax over the map's positions ignores;
    # - a3c_ww.py: for the same reason, the biases of its "where" maps, the second convolution's
    #   channels from what_maps on (convs.2.bias[what_maps:]); its "what" biases must learn.
    # (Such a gradient is zero up to rounding, so these may change a little: they are not checked.)
    model = shared.model
    no_gradient = {"a3c_ss": {"torso.2.bias"}}.get(name, set())
    after = dict(model.named_parameters())
    for key, old in zip(after, before, strict=True):
        new = after[key].detach()
        if name == "a3c_ww" and key == "convs.2.bias":
            what = slice(0, model.what_maps)
            assert not torch.equal(old[what], new[what]), f"{key}[:{model.what_maps}] did not learn"
        elif key not in no_gradient:
            assert not torch.equal(old, new), f"{key} did not learn"
    # logging the losses must not chain each rollout's graph onto the stats (a memory leak)
    assert shared.stats.grad_fn is None and not shared.stats.requires_grad


OPTIMIZER_STATISTICS = {"rmsprop": ("square_avg",), "adam": ("exp_avg", "exp_avg_sq")}


def checkpoint_round_trip(module, name, folder: Path, optimizer: str):
    """Save a Shared whose optimizer statistics are non-zero, restore it into a fresh Shared with
    another initial network, and check that the network, statistics and step came back."""
    args = tiny_args(module, optimizer=optimizer)
    shared = shared_for(module, args)
    shared.steps[0] = 1234
    for i, key in enumerate(OPTIMIZER_STATISTICS[optimizer]):
        for j, statistic in enumerate(getattr(shared.optimizer, key)):
            statistic.copy_(torch.rand_like(statistic) + i + j + 1)  # non-zero, all different
    if optimizer == "adam":
        shared.optimizer.step_count.fill_(37)
    path = folder / optimizer / "checkpoint.pt"
    path.parent.mkdir()
    runtime.save_checkpoint(path, shared, args, wall_time=12.0, script=f"{name}.py")
    checkpoint = runtime.load_checkpoint(str(path), module.AGENT)
    assert checkpoint["global_step"] == 1234 and checkpoint["wall_time"] == 12.0
    assert checkpoint["script"] == f"{name}.py" and checkpoint["optimizer_name"] == optimizer
    torch.manual_seed(123)  # another initial network
    fresh = shared_for(module, args)
    runtime.restore(fresh, checkpoint, args, str(path), module.AGENT)
    assert fresh.global_step() == 1234
    for p, q in zip(fresh.params, shared.params, strict=True):
        assert torch.equal(p, q)
    for key in OPTIMIZER_STATISTICS[optimizer]:
        restored, saved = getattr(fresh.optimizer, key), getattr(shared.optimizer, key)
        assert len(restored) == len(saved) == len(fresh.params)
        for r, s in zip(restored, saved, strict=True):
            assert (s != 0).all() and torch.equal(r, s), key
            assert r.is_shared()  # restored in place: the workers still share them
    if optimizer == "adam":
        assert fresh.optimizer.step_count.item() == 37 and fresh.optimizer.step_count.is_shared()
    return args, checkpoint, fresh, path


@pytest.mark.parametrize("name", SCRIPTS)
def test_checkpoint_round_trip_and_errors(name, tmp_path):
    module = load_script(name)
    checkpoint_round_trip(module, name, tmp_path, "adam")
    args, checkpoint, fresh, path = checkpoint_round_trip(module, name, tmp_path, "rmsprop")

    agent = module.AGENT
    with pytest.raises(runtime.UsageError, match="does not exist"):
        runtime.load_checkpoint(str(tmp_path / "missing.pt"), agent)
    (tmp_path / "garbage.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(runtime.UsageError, match="corrupt"):
        runtime.load_checkpoint(str(tmp_path / "garbage.pt"), agent)
    torch.save({"weights": 1}, tmp_path / "other.pt")
    with pytest.raises(runtime.UsageError, match="not a checkpoint written by this script"):
        runtime.load_checkpoint(str(tmp_path / "other.pt"), agent)
    elu = tiny_args(module, activation="elu")
    with pytest.raises(runtime.UsageError, match="--activation"):
        runtime.restore(fresh, checkpoint, elu, str(path), agent)
    checkpoint["model"]["value.weight"] = torch.zeros(5, 7)
    with pytest.raises(runtime.UsageError, match="does not fit") as error:
        runtime.restore(fresh, checkpoint, args, str(path), agent)
    assert "\n" not in str(error.value)


def main_exit(module, argv, monkeypatch, capsys) -> tuple[int, str]:
    """Run the script's main() in process, as `python agents/<script>.py *argv` would."""
    monkeypatch.setattr(sys, "argv", [f"{module.__name__}.py", *argv])
    try:
        code = module.main()
    except SystemExit as e:  # tyro's own errors
        code = e.code
    return code, capsys.readouterr().err


BAD_FLAGS = [
    (["--t-max", "0"], "error: --t-max must be >= 1 (got 0)"),
    (["--learning-rate", "nan"], "error: --learning-rate must be >= 0"),
    (["--env", "Nope-v0"], "error: unknown --env 'Nope-v0'; valid: Catch-v0"),
    (["--env", "CartPole-v1"], "error: --env CartPole-v1 gives no stacked 84x84 frames; valid: "),
    (["--resume", "/nonexistent/checkpoint.pt"], "error: checkpoint '/nonexistent/checkpoint.pt' "),
    (["--evaluate", "/nonexistent/checkpoint.pt"], "error: checkpoint '/nonexistent/"),
    (["--grad-clip-mode", "sideways"], "norm"),
    (["--rms-init", "-1"], "error: --rms-init must be >= 0 (got -1.0)"),
]


@pytest.mark.parametrize("name", SCRIPTS)
@pytest.mark.parametrize(("flags", "message"), BAD_FLAGS, ids=lambda v: " ".join(v)[:24])
def test_bad_flags_exit_2_with_one_line_and_create_nothing(
    name, flags, message, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)  # the default runs_root is ./runs
    code, err = main_exit(load_script(name), flags, monkeypatch, capsys)
    assert code == 2
    if message.startswith("error: "):
        assert err.startswith(message) and err.count("\n") == 1, err
    else:  # tyro's box around a Literal's choices
        assert message in err
    assert list(tmp_path.iterdir()) == []


VARIANT_FLAG_ERRORS = {
    "a3c_lws": ["--lws-kcps", "0"],
    "a3c_ss": ["--ss-initial-temperature", "0"],
    "a3c_ww": ["--ww-where-maps", "65"],
    "a3c_lstm": ["--lstm-cells", "0"],
    "a3c_lpq": ["--competition-size", "17"],
    "a3c_glpq": ["--temperature", "hot", "--p-end", "1"],
}


@pytest.mark.parametrize("name", VARIANT_FLAG_ERRORS)
def test_bad_variant_flags_are_refused_before_the_run_folder_exists(
    name, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    code, err = main_exit(load_script(name), VARIANT_FLAG_ERRORS[name], monkeypatch, capsys)
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
    assert list(tmp_path.iterdir()) == []


@pytest.fixture(scope="module")
def ff_checkpoints(tmp_path_factory) -> tuple[Path, Path]:
    """An a3c_ff.py checkpoint, and the same without the script name (as written before)."""
    module = load_script("a3c_ff")
    args = tiny_args(module)
    folder = tmp_path_factory.mktemp("ff")
    new, old = folder / "new" / "checkpoint.pt", folder / "old" / "checkpoint.pt"
    for path, script in ((new, "a3c_ff.py"), (old, "")):
        path.parent.mkdir()
        runtime.save_checkpoint(path, shared_for(module, args), args, 1.0, script=script)
    checkpoint = torch.load(old, weights_only=False)
    del checkpoint["script"]
    torch.save(checkpoint, old)
    return new, old


@pytest.mark.parametrize("name", [s for s in SCRIPTS if s != "a3c_ff"])
@pytest.mark.parametrize("mode", ["--resume", "--evaluate"])
def test_another_scripts_checkpoint_is_refused_naming_its_script(
    name, mode, ff_checkpoints, monkeypatch, capsys
):
    new, old = ff_checkpoints
    module = load_script(name)
    code, err = main_exit(module, [mode, str(new)], monkeypatch, capsys)
    assert code == 2 and "was written by a3c_ff.py, not " + name in err
    assert err.count("\n") == 1, err
    # one written before checkpoints named their script: its network does not fit
    code, err = main_exit(module, [mode, str(old)], monkeypatch, capsys)
    if name in ("a3c_ss", "a3c_ww", "a3c_lws"):  # their networks refuse already at a flag or key
        assert code == 2 and err.count("\n") == 1, err
    else:
        assert code == 2 and "does not fit this network (is it another script's?)" in err, err
        assert err.count("\n") == 1, err
    assert not list(new.parent.glob("events.*"))  # nothing written into the old run


def test_an_old_checkpoint_of_the_same_script_still_loads(ff_checkpoints):
    _, old = ff_checkpoints
    module = load_script("a3c_ff")
    checkpoint = runtime.load_checkpoint(str(old), module.AGENT)
    args = tiny_args(module)
    runtime.restore(shared_for(module, args), checkpoint, args, str(old), module.AGENT)


def test_evaluating_an_old_checkpoint_of_another_network_is_a_usage_error(ff_checkpoints):
    # no script name to refuse it by: the tensors of another shape give the one-line message
    _, old = ff_checkpoints
    module = load_script("a3c_ss")
    with pytest.raises(runtime.UsageError, match="does not fit this network: size mismatch"):
        runtime.evaluate(module.AGENT, module.Args(evaluate=str(old), eval_episodes=1))


@pytest.mark.parametrize("name", ["a3c_ss", "a3c_ww"])
def test_checkpoints_from_before_conv_layout_hold_the_final_network(name, tmp_path, capsys):
    """Such checkpoints have no --conv-layout: the script's checkpoint_defaults say "final"."""
    module = load_script(name)
    args = tiny_args(module, conv_layout="final")
    path = tmp_path / "checkpoint.pt"
    runtime.save_checkpoint(path, shared_for(module, args), args, 1.0, script="")
    checkpoint = torch.load(path, weights_only=False)
    del checkpoint["script"], checkpoint["args"]["conv_layout"]  # as written before the flag
    torch.save(checkpoint, path)
    loaded = runtime.load_checkpoint(str(path), module.AGENT)
    runtime.restore(shared_for(module, args), loaded, args, str(path), module.AGENT)
    with pytest.raises(runtime.UsageError, match="--conv-layout final, not ff"):
        default = tiny_args(module)
        runtime.restore(shared_for(module, default), loaded, default, str(path), module.AGENT)
    evaluate = module.Args(evaluate=str(path), eval_episodes=1)
    assert len(runtime.evaluate(module.AGENT, evaluate)) == 1
    assert "over 1 episodes" in capsys.readouterr().out


@pytest.mark.parametrize("name", SCRIPTS)
def test_evaluator_scores_the_initial_network_at_step_0(name, tmp_path):
    """No handshake: the evaluator gets a copy of the initial weights, taken before any worker
    could update the shared network; it stops with the run."""
    module = load_script(name)
    args = tiny_args(module, eval_episodes=2)
    shared = shared_for(module, args)
    initial = [p.detach().clone() for p in shared.params]
    with torch.no_grad():
        for p in shared.params:
            p.fill_(float("nan"))  # what the workers did meanwhile must not matter
    shared.stop.set()
    evaluations = FORK.SimpleQueue()
    runtime.evaluator(module.AGENT, shared, args, 0, initial, str(tmp_path), evaluations)
    result = evaluations.get()
    assert result["global_step"] == 0 and len(result["scores"]) == 2
    assert evaluations.empty()


def test_evaluate_plays_a_handful_of_episodes_when_rendering():
    args = SimpleNamespace(eval_episodes=None, render="human")
    assert runtime.evaluation_episodes(args) == runtime.HUMAN_EVAL_EPISODES == 5
    assert runtime.evaluation_episodes(SimpleNamespace(eval_episodes=None, render="none")) == 50
    assert runtime.evaluation_episodes(SimpleNamespace(eval_episodes=3, render="human")) == 3


def test_a_resumed_runs_progress_shows_its_last_evaluation(tmp_path, capsys):
    (tmp_path / "evaluations.csv").write_text(
        "global_step,wall_time_s,mean_return,std_return,episodes\n"
        "0,0.1,0.2,0.4,5\n2000,3.5,0.75,0.4,5\n"
    )
    args = SimpleNamespace(total_timesteps=4000, x=1)
    log = runtime.RunLog(tmp_path, args, wall_offset=3.6)
    log.progress(2500, 100.0, 1e-3, torch.zeros(len(runtime.Shared.STATS)))
    log.close()
    assert "| eval 0.750 @ 2,000 |" in capsys.readouterr().out


def test_phase_timer_splits_acting_into_forward_and_env_step():
    timer = runtime.PhaseTimer()
    env = timer.timed_env(load_script("a3c_ff").make_env("Catch-v0"))
    env.reset(seed=0)
    env.step(0)
    assert timer.env_seconds > 0
    timer.env_seconds = 0.25  # of a 1 s act phase
    timer.last -= 1.0
    timer.lap("act")
    assert timer.spent["env step"] == pytest.approx(0.25)
    assert timer.spent["act forward"] == pytest.approx(0.75, abs=0.05)
    assert timer.env_seconds == 0.0 and set(timer.spent) == set(runtime.PhaseTimer.PHASES)
