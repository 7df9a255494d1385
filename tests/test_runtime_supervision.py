"""a3c_runtime.supervision: a process's failure reaches the main process; SIGTERM ends a
worker's loop. Whole runs stopped by signals and killed workers: tests/test_runtime_a3c.py."""

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
    name, trace = errors.get()
    assert name == "worker 7" and "ZeroDivisionError" in trace


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
