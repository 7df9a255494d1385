"""Exact steps: evaluations and checkpoints are taken at the step the flags name, by the worker
whose update reaches it, and a checkpoint holds each worker's own state, so that a resumed run
is the run it continues.

A worker counts its steps with `Shared.count_steps` after each update. When the global step
reaches the next evaluation mark (a multiple of --eval-interval) or checkpoint mark (of
--checkpoint-interval), that worker copies theta there (and, for a checkpoint, the optimizer's
statistics and, with one worker, its own state: its random generator, its envs and the frames
it acts on next) and sends the copy to the main process (`Shared.events`), which hands
evaluations to the evaluator and writes checkpoints. With one worker every evaluation and
checkpoint is therefore of theta exactly at its step, and a run stopped anywhere (Ctrl-C,
SIGTERM, a killed main process after a checkpoint) and resumed ends with the same weights and
evaluations as the run that was not stopped. With several workers (Hogwild) the others go on
updating theta while the copy is taken, and their own states are saved only when the run stops
normally: evaluations are of theta at (about) their step, and a resumed run is a run like the
stopped one, not the same run.

A worker's state is kept as data, never pickled (a checkpoint stores it as flat tensors and its
declared document, a3c_runtime.checkpoint_file): its generator as its `bit_generator.state`,
arrays as tensors, and its envs as their own `get_state()` (Catch's vector env and its frame
stacks). What has no such form (ale-py's C++ vector env) is left out, and a resumed run makes
that part afresh (its envs start new games)."""

from __future__ import annotations

import contextlib
import pickle
import queue
from collections.abc import Callable
from typing import Any

import numpy as np
import torch

NEVER = 2**62  # a mark no run reaches: no snapshots until a run sets the marks
EVALUATE, CHECKPOINT, FINAL = "evaluate", "checkpoint", "final"


def saved_state(parts: tuple[Any, ...]) -> list[Any]:
    """Each part of a worker's state in a checkpoint's safe form, or None where it has none (it
    is made afresh on resume): a NumPy generator's `bit_generator.state`, an array as a tensor,
    a tensor (or a tuple of them, an LSTM's state) as it is, an env as its `get_state()`."""
    saved: list[Any] = []
    for part in parts:
        if isinstance(part, np.random.Generator):
            saved.append({"bit_generator": part.bit_generator.state})
        elif isinstance(part, np.ndarray):
            saved.append(torch.from_numpy(np.array(part, copy=True)))
        elif torch.is_tensor(part) or isinstance(part, tuple):
            saved.append(copy_of(part))
        elif callable(getattr(part, "get_state", None)):
            saved.append({"env": tensors_of(part.get_state())})
        else:
            saved.append(None)
    return saved


def restored_state(saved: list[Any], fresh: tuple[Any, ...]) -> tuple[Any, ...]:
    """The parts of a worker's state from `saved_state`'s form, each set into (or in place of)
    the fresh part the worker made, that part where none was saved."""
    restored = []
    for state, part in zip(saved, fresh, strict=True):
        if state is None:
            restored.append(part)
        elif isinstance(part, np.random.Generator):
            part.bit_generator.state = state["bit_generator"]
            restored.append(part)
        elif isinstance(part, np.ndarray):
            restored.append(state.numpy())
        elif callable(getattr(part, "set_state", None)):
            part.set_state(arrays_of(state["env"]))
            restored.append(part)
        else:
            restored.append(state)
    return tuple(restored)


def tensors_of(value: Any) -> Any:
    """NumPy arrays (and NumPy scalars) as tensors, through dicts, lists and tuples."""
    if isinstance(value, (np.ndarray, np.generic)):
        return torch.from_numpy(np.array(value, copy=True))
    if isinstance(value, dict):
        return {key: tensors_of(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(tensors_of(item) for item in value)
    return value


def arrays_of(value: Any) -> Any:
    """tensors_of reversed: tensors as NumPy arrays, through dicts, lists and tuples."""
    if torch.is_tensor(value):
        return value.numpy()
    if isinstance(value, dict):
        return {key: arrays_of(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return type(value)(arrays_of(item) for item in value)
    return value


def copy_of(tensors: Any) -> Any:
    """A detached copy of a state dict (or a nested list of tensors) to send elsewhere."""
    if torch.is_tensor(tensors):
        return tensors.detach().clone()
    if isinstance(tensors, dict):
        return {key: copy_of(value) for key, value in tensors.items()}
    if isinstance(tensors, (list, tuple)):
        return type(tensors)(copy_of(value) for value in tensors)
    return tensors


def next_mark(step: int, interval: int) -> int:
    """The first multiple of interval after step."""
    return (step // interval + 1) * interval


class MarkClock:
    """A run's next evaluation and checkpoint marks (multiples of --eval-interval and of
    --checkpoint-interval) in `marks`, a tensor that forked processes may share, and which of
    them an update reached: the one rule of both backends (StepMarks's workers, the batched
    backend's loop)."""

    def __init__(self, marks: torch.Tensor, args: Any = None, start_step: int = 0):
        self.marks = marks
        self.eval_interval = self.checkpoint_interval = self.total = NEVER
        if args is not None:
            self.eval_interval = args.eval_interval
            self.checkpoint_interval = args.checkpoint_interval
            self.total = args.total_timesteps
            self.marks[0] = next_mark(start_step, self.eval_interval)
            self.marks[1] = next_mark(start_step, self.checkpoint_interval)

    def reached(self, step: int) -> tuple[bool, bool]:
        """After an update that took the (global) step to `step`: whether it is an evaluation's
        (the one at T_max is the run's final evaluation, not a mark's) and a checkpoint's, each
        mark it reached moved past it."""
        evaluate = checkpoint = False
        if step >= int(self.marks[0]):
            evaluate = step < self.total
            self.marks[0] = next_mark(step, self.eval_interval)
        if step >= int(self.marks[1]):
            checkpoint = True
            self.marks[1] = next_mark(step, self.checkpoint_interval)
        return evaluate, checkpoint


class StepMarks:
    """The marks of the next evaluation and checkpoint, shared by the processes, and what a
    worker does when its update reaches one (see the module docstring)."""

    def __init__(self, ctx: Any):
        self.clock = MarkClock(torch.full((2,), NEVER, dtype=torch.int64).share_memory_())
        self.lock = ctx.Lock()  # one worker at a time takes a snapshot and moves the mark
        self.events = ctx.Queue()  # to the main process: (number, (kind, step, ...))
        # the marks' events are numbered as they are sent (under the lock): each process's queue
        # writes through its own thread, so they may arrive out of order; receive() restores it
        self.sent = torch.zeros(1, dtype=torch.int64).share_memory_()
        self.held: dict[int, tuple] = {}  # main process: events that came before an earlier one
        self.next_number = 0
        self.exact = False  # one worker: checkpoints carry its state
        self.resumed_states: dict[int, list[Any]] = {}

    def start(self, start_step: int, args: Any, resumed_states: dict | None) -> None:
        """Set the marks for a run from start_step (before the workers fork)."""
        self.clock = MarkClock(self.clock.marks, args, start_step)
        self.exact = args.num_workers == 1
        self.resumed_states = {int(k): v for k, v in (resumed_states or {}).items()}

    def reached(self, shared: Any, worker_id: int, step: int, state: Callable | None) -> None:
        """After an update that took the global step to `step`: the snapshots of the marks it
        reached, and the marks moved past it."""
        if step < int(self.clock.marks.min()):
            return
        with self.lock:
            evaluate, checkpoint = self.clock.reached(step)
            if evaluate:
                self.send(EVALUATE, step, copy_of(shared.model.state_dict()))
            if checkpoint:
                states = {worker_id: saved_state(state())} if self.exact and state else {}
                model = copy_of(shared.model.state_dict())
                optimizer = copy_of(shared.optimizer.state_dict())
                self.send(CHECKPOINT, step, model, optimizer, states)

    def finished(self, worker_id: int, state: Callable, orphaned: bool) -> None:
        """A worker's state as its loop ends, for the run's last checkpoint. With its main
        process gone, nothing: nobody will read it, and what this process sent but could not
        hand over must not hold it at its exit."""
        if orphaned:
            self.events.cancel_join_thread()
        elif int(self.clock.marks.min()) < NEVER:  # in a run (not a worker called by a test alone)
            self.send(FINAL, worker_id, saved_state(state()), numbered=False)  # in any order

    def send(self, *event: Any, numbered: bool = True) -> None:
        """An event for the main process, as bytes: tensors by value (torch's own pickling for
        multiprocessing would share them through a file descriptor of this process). A mark's
        event is numbered: it is sent with the lock held, in step order."""
        number = None
        if numbered:
            number = int(self.sent)
            self.sent += 1
        self.events.put(pickle.dumps((number, event)))

    def receive(self, every: bool = False) -> tuple | None:
        """The next event in the order the workers sent them (one that arrives before an earlier
        one waits for it), or None when there is none yet (in the main process). every=True,
        once the workers have ended: whatever is held, in order, past any gap (a worker killed
        while its event was on its way)."""
        while self.next_number not in self.held:
            try:
                number, event = pickle.loads(self.events.get_nowait())
            except queue.Empty:
                if not (every and self.held):
                    return None
                self.next_number = min(self.held)
                break
            if number is None:
                return event
            self.held[number] = event
        self.next_number += 1
        return self.held.pop(self.next_number - 1)

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.events.close()
            self.events.join_thread()
