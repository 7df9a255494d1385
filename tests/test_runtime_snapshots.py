"""a3c_runtime.snapshots: a worker whose update reaches an evaluation or checkpoint mark copies
theta there (and, with one worker, its own state), and a resumed worker gets its state back."""

import pickle
import queue
import time

import a3c_runtime as runtime
import numpy as np
import pytest
import safetensors.torch
import torch
from a3c_runtime.snapshots import (
    CHECKPOINT,
    EVALUATE,
    FINAL,
    NEVER,
    restored_state,
    saved_state,
)
from conftest import load_script, shared_for, tiny_args

import catch_env  # noqa: F401  (registers Catch-v0)


def events(shared) -> list[tuple]:
    found = []
    while True:
        try:
            _number, event = pickle.loads(shared.marks.events.get(timeout=0.5))
            found.append(event)
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
        shared.count_steps(0, 60, lambda: (rng, np.arange(3)))
    found = events(shared)
    kinds = [(event[0], event[1]) for event in found]
    assert kinds == [(EVALUATE, 120), (CHECKPOINT, 180), (EVALUATE, 240), (EVALUATE, 300),
                     (CHECKPOINT, 300), (CHECKPOINT, 480)]  # fmt: skip
    first_weight = next(iter(found[0][2].values()))
    assert torch.all(first_weight == 1)  # theta as the update reaching 120 left it
    step, model, optimizer, workers = found[1][1:]
    assert next(iter(model.values())).eq(2).all() and "square_avg" in optimizer
    saved = workers[0]  # one worker: its state, in the safe form
    assert saved[1].tolist() == [0, 1, 2]
    (restored,) = restored_state(saved[:1], (np.random.default_rng(5),))
    assert restored.random() == np.random.default_rng(0).random()


def test_no_snapshot_outside_a_run_and_none_of_a_worker_of_several():
    module = load_script("a3c_ff")
    args = tiny_args(module, eval_interval=100, checkpoint_interval=100)
    shared = shared_for(module, args)
    assert int(shared.marks.clock.marks.min()) == NEVER  # a worker alone (tests) sends nothing
    shared.count_steps(0, 500, lambda: ("state",))
    shared.finish_worker(0, lambda: ("state",))
    assert events(shared) == []
    args.num_workers = 2
    shared.marks.start(0, args, None)
    shared.count_steps(0, 100, lambda: ("state",))
    checkpoint = [e for e in events(shared) if e[0] == CHECKPOINT][0]
    assert checkpoint[4] == {}  # several workers: no one worker's state at a mark


def test_a_finished_worker_sends_its_state_unless_orphaned(run_shared):
    run_shared.finish_worker(0, lambda: (np.zeros(2), np.full(1, 3)))
    (event,) = events(run_shared)
    assert event[0] == FINAL and event[1] == 0 and event[2][1].tolist() == [3]
    run_shared.marks.finished(0, lambda: ("envs",), orphaned=True)
    assert events(run_shared) == []


class NoState:
    """A part of a worker's state with no safe form (as ale-py's C++ vector env)."""


def test_a_resumed_worker_gets_what_was_saved_and_keeps_the_rest(tmp_path):
    """The state goes through a checkpoint as a run writes it (save_checkpoint) and --resume
    reads it (load_checkpoint, the gate): the generator, the frames, an LSTM's state and Catch's
    envs come back, the envs playing on as the saved ones do; a part with no such form (as
    ale-py's C++ vector env) is not saved, and a resumed worker keeps the fresh one."""
    from catch_env.wrappers import make_vector_env

    module = load_script("a3c_lstm")
    args = tiny_args(module, envs_per_worker=3)
    shared = shared_for(module, args)
    envs = make_vector_env("Catch-v0", 3)
    envs.reset(seed=4)
    for t in range(7):
        frames = envs.step(np.array([t % 3, 1, 2]))[0].copy()
    lstm = tuple(torch.rand_like(s) for s in shared.model.initial_state(3))
    workers = {0: saved_state((np.random.default_rng(3), envs, frames, lstm)),
               1: saved_state((np.random.default_rng(5), NoState(), frames, lstm))}  # fmt: skip
    path = tmp_path / "checkpoint.pt"
    runtime.save_checkpoint(path, shared, args, 1.0, module.AGENT.script, {"workers": workers})
    saved = runtime.load_checkpoint(str(path), module.AGENT).workers
    assert saved[1][1] is None  # not saved, made afresh on resume
    fresh_envs, no_state = make_vector_env("Catch-v0", 3), NoState()
    fresh_envs.reset(seed=99)
    fresh = (np.random.default_rng(9), fresh_envs, np.zeros_like(frames), None)
    rng, restored_envs, obs, state = restored_state(saved[0], fresh)
    assert rng.random() == np.random.default_rng(3).random()
    assert obs.dtype == np.uint8 and np.array_equal(obs, frames)
    assert isinstance(state, tuple) and all(map(torch.equal, state, lstm))
    assert restored_envs is fresh_envs
    for t in range(40):  # the same games on: frames, rewards, ends, and new games' starts
        actions = np.array([t % 3, (t + 1) % 3, 0])
        ours, theirs = restored_envs.step(actions), envs.step(actions)
        for a, b in zip(ours[:4], theirs[:4], strict=True):
            assert np.array_equal(a, b)
    rng, kept, obs, _ = restored_state(saved[1], (np.random.default_rng(9), no_state, obs, None))
    assert kept is no_state and rng.random() == np.random.default_rng(5).random()
    shared.marks.start(0, args, {"0": saved_state((np.arange(2),))})
    assert shared.resumed(0, np.zeros(2))[0].tolist() == [0, 1]
    assert shared.resumed(1, "fresh") == ("fresh",)  # a worker the checkpoint did not keep


def test_an_env_state_of_another_shape_is_refused_and_changes_nothing():
    from catch_env.wrappers import make_vector_env

    two, three = make_vector_env("Catch-v0", 2), make_vector_env("Catch-v0", 3)
    two.reset(seed=1)
    three.reset(seed=2)
    before = three.get_state()
    with pytest.raises(ValueError, match="shape"):
        three.set_state(two.get_state())
    after = three.get_state()
    assert np.array_equal(before["stack"], after["stack"])
    assert before["env"]["rngs"] == after["env"]["rngs"]


def test_the_main_process_receives_the_marks_events_in_the_order_they_were_sent():
    """Each process's queue writes through its own thread, so a later worker's event can
    arrive first: it waits for the earlier one; once the workers have ended, a gap (an event
    lost with its worker) is passed over."""
    module = load_script("a3c_ff")
    marks = shared_for(module, tiny_args(module)).marks
    for number, step in ((1, 2000), (3, 4000), (0, 1000)):
        marks.events.put(pickle.dumps((number, (EVALUATE, step))))
    marks.events.put(pickle.dumps((None, (FINAL, 1, []))))  # not numbered: at once
    received = []
    while len(received) < 3:  # (the queue's thread hands them over when it runs)
        event = marks.receive()
        if event is not None:
            received.append(event[:2])
    assert received == [(EVALUATE, 1000), (EVALUATE, 2000), (FINAL, 1)]
    assert marks.receive() is None  # 4000 waits for 3000, which never comes
    assert marks.receive(every=True)[1] == 4000 and marks.receive(every=True) is None


def test_a_marks_checkpoint_holds_the_optimizer_statistics_of_its_step(
    tmp_path, monkeypatch, capsys
):
    """A run's checkpoint at a mark holds the optimizer statistics as they were at its step,
    with theta's, however late the main process writes it: the worker goes on updating them
    meanwhile (here the main process takes 0.3 s to write each), and a run resumed from it must
    go on from the statistics of its step. One worker, Catch, in process."""
    import a3c_runtime.a3c
    from a3c_runtime.snapshots import StepMarks
    from conftest import main_exit, read_checkpoint

    at_step = tmp_path / "at_step"
    at_step.mkdir()
    reached = StepMarks.reached

    def recorded_reached(self, shared, worker_id, step, state):
        due = step >= int(self.clock.marks[1])
        reached(self, shared, worker_id, step, state)
        if due:  # in the worker, just after its snapshot: the statistics of the mark's step
            square_avg = shared.optimizer.state_dict()["square_avg"]
            recorded = {str(i): s.contiguous().clone() for i, s in enumerate(square_avg)}
            safetensors.torch.save_file(recorded, at_step / str(step))

    monkeypatch.setattr(StepMarks, "reached", recorded_reached)  # the worker forks with it
    written = []
    save = a3c_runtime.a3c.save_checkpoint

    def late_save(path, *args, **kwargs):
        time.sleep(0.3)
        save(path, *args, **kwargs)
        written.append(read_checkpoint(path))

    monkeypatch.setattr(a3c_runtime.a3c, "save_checkpoint", late_save)
    flags = ["--num-workers", "1", "--total-timesteps", "300", "--t-max", "20",
             "--checkpoint-interval", "100", "--eval-interval", "300", "--eval-episodes", "1",
             "--log-interval", "60", "--run-dir", str(tmp_path / "run")]  # fmt: skip
    code, err = main_exit(load_script("a3c_ff"), flags, monkeypatch, capsys)
    assert code == 0, err
    marks = [c for c in written if c["global_step"] < 300]
    assert len(marks) == 2  # the first steps at or past 100 and 200
    for checkpoint in marks:
        then = safetensors.torch.load_file(at_step / str(checkpoint["global_step"]))
        then = [then[str(i)] for i in range(len(then))]
        for saved, expected in zip(checkpoint["optimizer"]["square_avg"], then, strict=True):
            assert torch.equal(saved, expected)
    last = written[-1]["optimizer"]["square_avg"]
    assert not all(torch.equal(a, b) for a, b in zip(last, then, strict=True))


def test_a_saved_worker_state_is_a_copy_of_its_arrays_at_that_moment():
    """A snapshot goes to the main process after the worker has moved on: its frames must be
    those of its step, not the buffer the worker keeps writing."""
    frames = np.arange(12, dtype=np.uint8).reshape(3, 4)
    tensor = torch.arange(4.0)
    saved = saved_state((frames, tensor))
    frames[:] = 0
    tensor[:] = -1
    np.testing.assert_array_equal(saved[0].numpy(), np.arange(12).reshape(3, 4))
    torch.testing.assert_close(saved[1], torch.arange(4.0))
