"""Processes and signals: the forked actor-learners and evaluator, what each sets first, how the
main process watches them, and how a run stops (the end, a time limit, Ctrl-C or SIGTERM, or a
process that died)."""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
import time
import traceback
from collections.abc import Callable
from typing import Any

import torch
import torch.multiprocessing as mp

from .hogwild import Shared

# fork: a fast start, and it works when a script is loaded by path (spawn would re-import it)
FORK = mp.get_context("fork")


class RunFailed(RuntimeError):
    """A worker or the evaluator died; the message holds its traceback."""


def configure_process() -> None:
    """What every worker and evaluator process sets first: one torch thread, and denormals
    flushed. (Telling glibc's malloc to keep freed memory gained 2% on the fast setting and
    under 1% at K = 1, so it was removed: results/throughput_package/COMMAND.txt.)"""
    torch.set_num_threads(1)
    torch.set_flush_denormal(True)  # decayed RMSprop statistics must not turn into slow denormals


def run_process(
    name: str, errors: Any, shared: Shared, target: Callable[..., None], *target_args: Any
) -> None:
    """Process entry: leave SIGINT to the main process (the terminal sends it to the whole
    group); SIGTERM ends the loop (shared.keep_running); an exception goes to `errors` as
    (name, trace)."""

    def on_sigterm(_signum: int, _frame: Any) -> None:
        shared.signalled = True

    die_with(getattr(shared, "main_pid", None))
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, on_sigterm)
    configure_process()
    try:
        target(*target_args)
    except BaseException:
        errors.put((name, traceback.format_exc()))
        sys.exit(1)


def die_with(main_pid: int | None) -> None:
    """On Linux, the kernel kills this forked process (SIGKILL) when the main process ends,
    however it ends (PR_SET_PDEATHSIG), so that nothing of a run outlives it: not a process
    blocked on a pipe the main process was writing when it was killed, nor one that was stopped
    (SIGSTOP) meanwhile. Elsewhere the processes notice a dead main process themselves
    (Shared.orphaned), within a rollout or an episode."""
    if sys.platform.startswith("linux"):
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if main_pid is not None and os.getppid() != main_pid:  # it ended before the request
        os._exit(1)


PR_SET_PDEATHSIG = 1


def describe_exit(exitcode: int) -> str:
    if exitcode < 0:
        return f"was killed by {signal.Signals(-exitcode).name}"
    return f"exited with code {exitcode}"


class Supervisor:
    """Starts the named processes (each `(target, *args)`), collects their failures, and stops
    them. While it runs, SIGINT and SIGTERM in the main process set `shared.signalled` (which
    also ends evaluation episodes played here) and are remembered in `signal_name`."""

    def __init__(self, shared: Shared, targets: dict[str, tuple[Any, ...]]):
        self.shared = shared
        self.errors = FORK.SimpleQueue()
        self.failures: list[str] = []
        self.signal_name: str | None = None
        self.previous_handlers = {
            s: signal.signal(s, self._on_signal) for s in (signal.SIGINT, signal.SIGTERM)
        }
        self.processes = {
            name: FORK.Process(
                target=run_process, args=(name, self.errors, shared, *target), daemon=True
            )
            for name, target in targets.items()
        }
        for process in self.processes.values():
            process.start()

    def _on_signal(self, signum: int, _frame: Any) -> None:
        self.shared.signalled = True
        if self.signal_name is None:
            self.signal_name = signal.Signals(signum).name

    def pids(self) -> str:
        return ", ".join(f"{name} {p.pid}" for name, p in self.processes.items())

    def exit_codes(self) -> dict[str, int | None]:
        return {name: process.exitcode for name, process in self.processes.items()}

    def read_errors(self) -> None:
        """The failures the processes reported (name and traceback)."""
        while not self.errors.empty():
            name, trace = self.errors.get()
            self.failures.append(f"{name} failed:\n{trace}")

    def check_exits(self, codes: dict[str, int | None], global_step: int, total: int) -> None:
        """A process that ended, from exit codes read before global_step: exit 0 is only
        expected of a worker that reached T_max."""
        if self.failures:
            return
        for name, code in codes.items():
            early = name == "evaluator" or global_step < total
            if code is not None and (code != 0 or early):
                self.failures.append(
                    f"{name} (pid {self.processes[name].pid}) {describe_exit(code)}"
                )
                return

    @staticmethod
    def workers_done(codes: dict[str, int | None]) -> bool:
        return all(code == 0 for name, code in codes.items() if name != "evaluator")

    def stop_workers(self, drain: Callable[[], None] = lambda: None) -> None:
        """The workers end their loops (after their rollout) and exit; drain() reads what they
        send meanwhile (a worker's last snapshot waits in its queue until it is read)."""
        self.shared.stop.set()
        deadline = time.time() + 10
        for name, process in self.processes.items():
            if name == "evaluator":
                continue
            while process.is_alive() and time.time() < deadline:
                drain()
                process.join(0.05)
            if process.is_alive():
                process.kill()
                process.join(1)

    def stop(self, finished: bool, drain: Callable[[], None] = lambda: None) -> None:
        """Stop every process: the workers finish their rollout; a finished run's evaluator
        takes the evaluations it was handed (unless a signal comes), any other's drops the one
        it plays at once."""
        self.stop_workers(drain)
        evaluator = self.processes.get("evaluator")
        if evaluator is not None:
            if not finished:
                evaluator.terminate()  # SIGTERM: it drops the evaluation it plays
            while evaluator.is_alive() and finished and self.signal_name is None:
                drain()
                evaluator.join(0.05)
            if self.signal_name is not None:
                evaluator.terminate()
            deadline = time.time() + 10
            while evaluator.is_alive() and time.time() < deadline:
                drain()
                evaluator.join(0.05)
            if evaluator.is_alive():
                evaluator.kill()
                evaluator.join(1)
        self.read_errors()
        evaluator_failed = evaluator is not None and evaluator.exitcode not in (0, None)
        if evaluator_failed and finished and self.signal_name is None and not self.failures:
            self.failures.append(f"evaluator {describe_exit(evaluator.exitcode)}")

    def restore_signal_handlers(self) -> None:
        for s, handler in self.previous_handlers.items():
            signal.signal(s, handler)
