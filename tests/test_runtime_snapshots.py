"""a3c_runtime.snapshots: a worker whose update reaches an evaluation or checkpoint mark copies
theta there (and, with one worker, its own state), and a resumed worker gets its state back."""

import pickle
import queue

import numpy as np
import pytest
import torch
from a3c_runtime.snapshots import CHECKPOINT, EVALUATE, FINAL, NEVER, pickled, unpickled
from conftest import load_script, shared_for, tiny_args

import catch_env  # noqa: F401  (registers Catch-v0)


def events(shared) -> list[tuple]:
    found = []
    while True:
        try:
            found.append(pickle.loads(shared.marks.events.get(timeout=0.5)))
        except queue.Empty:
            return found


@pytest.fixture
def run_shared():
    module = load_script("a3c_ff")
    args = tiny_args(module, eval_interval=100, checkpoint_interval=150, total_timesteps=400)
    shared = shared_for(module, args)
    shared.marks.start(0, args, None)
    return shared


def test_the_update_that_reaches_a_mark_copies_theta_there(run_shared):
    """Updates of 60 steps: the evaluations at 120, 240 and 300 (the first step at or past each
    multiple of 100; at 420 it would be past T_max, whose evaluation is the run's final one),
    the checkpoints at 180, 300 (after the evaluation of the same update) and 480."""
    shared = run_shared
    rng = np.random.default_rng(0)
    for update in range(8):  # 60 ... 480
        with torch.no_grad():
            shared.params[0].fill_(update)  # theta after this update
        shared.count_steps(0, 60, lambda: (rng, "envs"))
    found = events(shared)
    kinds = [(event[0], event[1]) for event in found]
    assert kinds == [(EVALUATE, 120), (CHECKPOINT, 180), (EVALUATE, 240), (EVALUATE, 300),
                     (CHECKPOINT, 300), (CHECKPOINT, 480)]  # fmt: skip
    first_weight = next(iter(found[0][2].values()))
    assert torch.all(first_weight == 1)  # theta as the update reaching 120 left it
    step, model, optimizer, workers = found[1][1:]
    assert next(iter(model.values())).eq(2).all() and "square_avg" in optimizer
    saved = workers[0]  # one worker: its state, pickled
    assert pickle.loads(saved[1]) == "envs"
    assert pickle.loads(saved[0]).random() == np.random.default_rng(0).random()


def test_no_snapshot_outside_a_run_and_none_of_a_worker_of_several():
    module = load_script("a3c_ff")
    args = tiny_args(module, eval_interval=100, checkpoint_interval=100)
    shared = shared_for(module, args)
    assert int(shared.marks.marks.min()) == NEVER  # a worker called alone (tests) sends nothing
    shared.count_steps(0, 500, lambda: ("state",))
    shared.finish_worker(0, lambda: ("state",))
    assert events(shared) == []
    args.num_workers = 2
    shared.marks.start(0, args, None)
    shared.count_steps(0, 100, lambda: ("state",))
    checkpoint = [e for e in events(shared) if e[0] == CHECKPOINT][0]
    assert checkpoint[4] == {}  # several workers: no one worker's state at a mark


def test_a_finished_worker_sends_its_state_unless_orphaned(run_shared):
    run_shared.finish_worker(0, lambda: ("envs", 3))
    (event,) = events(run_shared)
    assert event[0] == FINAL and event[1] == 0 and pickle.loads(event[2][1]) == 3
    run_shared.marks.finished(0, lambda: ("envs",), orphaned=True)
    assert events(run_shared) == []


class Unpicklable:
    closed = False

    def __reduce__(self):
        raise TypeError("cannot pickle")

    def close(self):
        self.closed = True


def test_a_resumed_worker_gets_what_was_saved_and_keeps_the_rest():
    saved = pickled((np.random.default_rng(3), Unpicklable(), [1, 2]))
    assert saved[1] is None  # ale-py's vector env: not saved, made afresh on resume
    fresh_rng, fresh_envs, fresh_list = np.random.default_rng(9), Unpicklable(), [0]
    rng, envs, values = unpickled(saved, (fresh_rng, fresh_envs, fresh_list))
    assert rng.random() == np.random.default_rng(3).random()
    assert envs is fresh_envs and not envs.closed and values == [1, 2]
    module = load_script("a3c_ff")
    args = tiny_args(module)
    shared = shared_for(module, args)
    shared.marks.start(0, args, {"0": pickled(("saved",))})
    assert shared.resumed(0, "fresh") == ("saved",)
    assert shared.resumed(1, "fresh") == ("fresh",)  # a worker the checkpoint did not keep
