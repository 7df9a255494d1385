"""a3c_runtime.supervision: a process's failure reaches the main process; SIGTERM ends a
worker's loop. Whole runs stopped by signals and killed workers: tests/test_runtime_a3c.py."""

import os
from types import SimpleNamespace

import a3c_runtime as runtime
from conftest import FORK

import catch_env  # noqa: F401  (registers Catch-v0)


def test_run_process_reports_exceptions():
    errors = FORK.SimpleQueue()
    shared = SimpleNamespace(signalled=False)
    child = FORK.Process(
        target=runtime.run_process, args=("worker 7", errors, shared, lambda: 1 / 0)
    )
    child.start()
    child.join(30)
    assert child.exitcode == 1
    assert not errors.empty()  # (a get() would wait for ever on a child that put nothing)
    name, trace = errors.get()
    assert name == "worker 7" and "ZeroDivisionError" in trace


def test_a_process_whose_main_process_ended_before_it_started_ends_at_once():
    """A forked process whose main process is not its parent any more (it died before the
    child asked the kernel to kill it with it) exits at once, code 1, running nothing; one
    whose main process is its parent runs."""
    errors = FORK.SimpleQueue()
    for main_pid, runs in ((os.getpid(), True), (1, False)):  # pid 1: never the child's parent
        shared = SimpleNamespace(signalled=False, main_pid=main_pid)
        child = FORK.Process(
            target=runtime.run_process, args=("worker 0", errors, shared, lambda: 1 / 0)
        )
        child.start()
        child.join(30)
        assert child.exitcode == 1
        assert errors.empty() is not runs, main_pid  # the target ran and failed, or never ran
        while not errors.empty():
            errors.get()


def _loop_until_signalled(shared, ready) -> None:
    ready.set()
    while not shared.signalled:
        pass


def test_sigterm_ends_a_processs_loop_cleanly():
    errors, ready = FORK.SimpleQueue(), FORK.Event()
    shared = SimpleNamespace(signalled=False)
    child = FORK.Process(
        target=runtime.run_process,
        args=("worker 0", errors, shared, _loop_until_signalled, shared, ready),
    )
    child.start()
    assert ready.wait(30)
    child.terminate()  # SIGTERM
    child.join(30)
    assert child.exitcode == 0 and errors.empty()
    assert not shared.signalled  # the flag is the child's own


def test_an_evaluator_that_dies_in_a_finished_runs_last_evaluations_is_a_failure():
    """The run is finished and its evaluator, taking the evaluations it was handed, dies
    without a word (killed, say): the run fails, naming it, rather than ending "done" with
    evaluations missing. A worker that reached T_max (exit 0) is no failure."""
    import threading

    shared = SimpleNamespace(signalled=False, main_pid=os.getpid(), stop=threading.Event())
    supervisor = runtime.supervision.Supervisor(
        shared, {"worker 0": (lambda: None,), "evaluator": (lambda: os._exit(3),)}
    )
    try:
        supervisor.stop(finished=True)
    finally:
        supervisor.restore_signal_handlers()
    assert supervisor.failures == ["evaluator exited with code 3"], supervisor.failures


def test_a_process_that_ends_is_a_failure_unless_a_worker_reached_t_max():
    """Exit 0 is what a worker returns at T_max. Before it (a worker loop that ended early), from
    the evaluator at any time, or with any other code, a process that ended is a failure, named
    with its pid and how it ended; one still running (None) is not."""
    import threading

    shared = SimpleNamespace(signalled=False, main_pid=os.getpid(), stop=threading.Event())
    supervisor = runtime.supervision.Supervisor(
        shared, {"worker 0": (lambda: None,), "evaluator": (lambda: None,)}
    )
    try:
        pids = {name: process.pid for name, process in supervisor.processes.items()}
        cases = [
            ({"worker 0": 0, "evaluator": None}, 100, []),
            ({"worker 0": None, "evaluator": None}, 50, []),
            ({"worker 0": 0, "evaluator": None}, 99, [f"worker 0 (pid {pids['worker 0']}) "
                                                     "exited with code 0"]),
            ({"worker 0": 2, "evaluator": None}, 100, [f"worker 0 (pid {pids['worker 0']}) "
                                                      "exited with code 2"]),
            ({"worker 0": None, "evaluator": 0}, 100, [f"evaluator (pid {pids['evaluator']}) "
                                                      "exited with code 0"]),
            ({"worker 0": -9, "evaluator": None}, 50, [f"worker 0 (pid {pids['worker 0']}) "
                                                      "was killed by SIGKILL"]),
        ]  # fmt: skip
        for codes, step, failures in cases:
            supervisor.failures.clear()
            supervisor.check_exits(codes, step, total=100)
            assert supervisor.failures == failures, (codes, step)
    finally:
        for process in supervisor.processes.values():
            process.join(30)
        supervisor.restore_signal_handlers()
