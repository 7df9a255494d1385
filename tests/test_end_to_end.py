"""End to end, in process: one whole run (train(): two forked workers and the evaluator) per
distinct worker loop, and one on Atari. Each asserts what the run must show: the target step
reached, an evaluation at each step the flags ask for, and a final checkpoint that loads into a
fresh network and gives the action probabilities of the network that wrote it; the growth scripts'
runs also resume from their last growth round. The scripts that share a loop (LWS, SS, WW, LPQ and
chapter 8's value-head, data-init and online-LWS scripts run FF's) are tested in process by
tests/test_workers.py."""

import copy

import a3c_runtime as runtime
import pytest
import torch
from conftest import load_script, main_exit, read_checkpoint, read_evaluations
from test_script_drift import PAIRS

# the scripts whose worker loop is their own (each drift pair that may change `worker`), and FF
LOOPS = ["a3c_ff", "a3c_lstm", "a3c_glpq", "a3c_lpq_growth", "a3c_glpq_growth"]
STEPS, INTERVAL = 2000, 500


def test_every_distinct_worker_loop_has_its_run():
    own_loop = {derived for (_, derived), names in PAIRS.items() if "worker" in names}
    assert set(LOOPS) == {"a3c_ff"} | own_loop


def run_and_check(name, flags, tmp_path, monkeypatch, capsys, steps, interval, actions):
    """Run the script in process; check its evaluations, final step and checkpoint."""
    saved = {}
    save = runtime.a3c.save_checkpoint

    def save_and_keep(path, shared, args, wall_time, script="", snapshot=None):
        model = (snapshot or {}).get("model") or shared.model.state_dict()
        saved["model"], saved["args"] = copy.deepcopy(model), args
        return save(path, shared, args, wall_time, script, snapshot)

    monkeypatch.setattr(runtime.a3c, "save_checkpoint", save_and_keep)
    module = load_script(name)
    argv = [
        *flags,
        *("--num-workers", "2", "--total-timesteps", str(steps)),
        *("--eval-interval", str(interval), "--run-dir", str(tmp_path)),
    ]
    code, err = main_exit(module, argv, monkeypatch, capsys, keep_out=True)
    out = capsys.readouterr().out
    assert code == 0, err
    assert out.strip().splitlines()[-1].startswith("done: final eval")
    rows = read_evaluations(tmp_path)
    evaluated = [int(row["global_step"]) for row in rows]
    # one evaluation at step 0, one at each interval (once the global step has passed it: the
    # workers count whole updates), and the final one after T_max
    marks = list(range(0, steps, interval))
    assert len(evaluated) == len(marks) + 1, evaluated
    for mark, step in zip(marks, evaluated, strict=False):
        assert mark <= step < mark + interval, (mark, evaluated)
    assert evaluated[-1] >= steps
    checkpoint = runtime.load_checkpoint(str(tmp_path / "checkpoint.pt"), module.AGENT)
    assert checkpoint.global_step == evaluated[-1] >= steps
    # the checkpoint's network is the network that wrote it: same action probabilities
    writer = module.AGENT.build_network(actions, saved["args"])
    writer.load_state_dict(saved["model"])
    loaded = module.AGENT.build_network(actions, saved["args"])
    runtime.load_network(loaded, checkpoint, "checkpoint.pt")
    obs = torch.randint(0, 256, (5, 4, 84, 84), dtype=torch.uint8)

    @torch.no_grad()
    def probabilities(net: torch.nn.Module) -> torch.Tensor:
        if name == "a3c_lstm":  # one step from the initial state for each observation
            return net(obs[None], net.initial_state(len(obs)))[0][0].exp()
        return net(obs)[0].exp()

    torch.testing.assert_close(probabilities(loaded), probabilities(writer), rtol=0, atol=0)
    fresh = module.AGENT.build_network(actions, saved["args"])
    assert not torch.equal(probabilities(fresh), probabilities(writer))  # it trained


@pytest.mark.slow
@pytest.mark.parametrize("name", LOOPS)
def test_a_whole_run_of_each_worker_loop(name, tmp_path, monkeypatch, capsys):
    flags = ["--envs-per-worker", "4", "--eval-episodes", "2"]  # K > 1: the replay's path too
    if name.endswith("_growth"):
        flags += ["--growth-interval", "500", "--growth-ratio", "1e-6"]
    run_and_check(name, flags, tmp_path, monkeypatch, capsys, STEPS, INTERVAL, actions=3)
    if name.endswith("_growth"):
        # the checkpoint holds the last growth round, and a resumed run goes on from it (worker
        # 0 grows between its updates, so how many rounds ran depends on its share of the CPU;
        # test_future_work's test_growth_rounds_survive_a_resume pins the rounds down)
        def rounds() -> tuple[int, int]:
            checkpoint = read_checkpoint(tmp_path / "checkpoint.pt")
            return int(checkpoint["model"]["growth_round"]), checkpoint["global_step"] // 500

        before, due = rounds()
        assert 1 <= before <= due, (before, due)
        resume = ["--resume", str(tmp_path / "checkpoint.pt"), "--total-timesteps", "3000"]
        code, err = main_exit(load_script(name), resume, monkeypatch, capsys)
        assert code == 0, err
        after, due = rounds()
        assert before <= after <= due == 6, (before, after, due)


@pytest.mark.slow
def test_a_whole_run_on_atari(tmp_path, monkeypatch, capsys):
    pytest.importorskip("ale_py")
    flags = ["--env", "BreakoutNoFrameskip-v4", "--envs-per-worker", "4", "--eval-episodes", "1"]
    run_and_check("a3c_ff", flags, tmp_path, monkeypatch, capsys, 800, 400, actions=4)
