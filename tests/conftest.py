"""Shared helpers and fixtures of the tests: load an agent script by path, run it as a
subprocess, tiny runs, a worker's one-thread torch, a script's main() in process.

The scripts import the a3c_runtime package, installed with the agents distribution
(pip install -e ./agents); running one by path also finds it beside the script."""

from __future__ import annotations

import contextlib
import csv
import importlib.util
import io
import multiprocessing
import os
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import a3c_runtime as runtime
import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]
AGENTS = ROOT / "agents"

FORK = multiprocessing.get_context("fork")
# every agent script, found on disk so that a new one is tested without being listed: the
# thesis's (agents/a3c_*.py) and chapter 8's ideas (agents/future_work/a3c_*.py), by file stem
SCRIPT_PATHS = {
    path.stem: path
    for folder in (AGENTS, AGENTS / "future_work")
    for path in sorted(folder.glob("a3c_*.py"))
}
SCRIPTS = tuple(name for name, path in SCRIPT_PATHS.items() if path.parent == AGENTS)
FUTURE_WORK = tuple(name for name in SCRIPT_PATHS if name not in SCRIPTS)
ALL_SCRIPTS = SCRIPTS + FUTURE_WORK
# a tiny run: 2 workers, 5 evaluation episodes, a progress line every second
TINY = ["--num-workers", "2", "--eval-episodes", "5", "--log-interval", "1"]


def load_script(name: str) -> ModuleType:
    """Import the agent script <name>.py (agents/ or agents/future_work/) as a module named
    after its file (once per test session)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, SCRIPT_PATHS[name])
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def run_script(name: str, *flags: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """Run the agent script <name>.py by path, as a user does, from the repository root."""
    return subprocess.run(
        [sys.executable, str(SCRIPT_PATHS[name]), *flags],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=ROOT,
    )


def run_into_a_closed_pipe(argv: list[str], timeout: float = 60) -> subprocess.CompletedProcess:
    """Run a command whose stdout is a pipe with no reader left (as after `| head -1` has
    exited): every write to it fails with EPIPE, at once and every time."""
    read, write = os.pipe()
    os.close(read)
    try:
        return subprocess.run(
            argv, stdout=write, stderr=subprocess.PIPE, text=True, timeout=timeout, cwd=ROOT
        )
    finally:
        os.close(write)


def read_evaluations(run_dir: Path) -> list[dict]:
    with open(run_dir / "evaluations.csv") as f:
        return list(csv.DictReader(f))


def evaluation_steps(run_dir: Path) -> list[int]:
    return [int(row["global_step"]) for row in read_evaluations(run_dir)]


def tiny_args(module: ModuleType, **flags):
    """A script's Args for one worker, defaults resolved."""
    return runtime.resolve_defaults(module.Args(num_workers=1, **flags))


def shared_for(module: ModuleType, args, num_actions: int = 3) -> runtime.Shared:
    """The Shared of a run of the script with these Args, in this process."""
    return runtime.Shared(module.AGENT.build_network(num_actions, args), args, FORK)


def read_checkpoint(path: Path | str) -> dict:
    """A checkpoint's contents as save_checkpoint hands them to the file (its document's fields,
    its tensors by part), read as the project reads them."""
    from a3c_runtime.checkpoint_file import read_checkpoint as read
    from a3c_runtime.checkpoint_file import read_tensors

    document, _, data = read(str(path))
    return {**document, **read_tensors(data, document, str(path))}


def rewrite_checkpoint(path: Path | str, checkpoint: dict, checked: bool = True) -> None:
    """Write checkpoint's contents to path as save_checkpoint writes them (sealed): a checkpoint
    changed on purpose, as an older script or another tool would have written it (checked=False:
    whatever its document holds, as a hostile writer would)."""
    Path(path).write_bytes(runtime.checkpoints.encode(checkpoint, checked))


@pytest.fixture
def one_thread():
    """A worker's torch: one thread (run_process sets it in a real run)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def main_exit(
    module: ModuleType, argv: list[str], monkeypatch, capsys, keep_out: bool = False
) -> tuple[int, str]:
    """Run the script's main() in process, as `python agents/<script>.py *argv` would: (its exit
    code, its stderr); with keep_out, stdout stays in capsys for the caller (and stderr too)."""
    monkeypatch.setattr(sys, "argv", [f"{module.__name__}.py", *argv])
    try:
        code = module.main()
    except SystemExit as e:  # tyro's own errors, --help
        code = e.code
    return code, "" if keep_out else capsys.readouterr().err


def run_main(main, argv: list[str], cwd: Path = ROOT) -> subprocess.CompletedProcess:
    """A tool's main(argv) in process, from cwd, as `python -m <tool> *argv` would run it: its
    exit code (argparse's SystemExit included), stdout and stderr."""
    out, err, before = io.StringIO(), io.StringIO(), os.getcwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(list(argv))
            except SystemExit as e:
                code = e.code
    finally:
        os.chdir(before)
    return subprocess.CompletedProcess(argv, code or 0, out.getvalue(), err.getvalue())


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """A test whose module has a `start_at_collection` function (tests/test_learning.py's runs)
    runs last in one process: its work starts once collection ends (below) and goes on beside
    the other tests, which mostly wait on processes and leave a core free. Under pytest-xdist
    (-n) it runs first instead, in one worker, and starts its work itself; the other tests
    go to the others, and to that one once it is done."""
    under_xdist = hasattr(config, "workerinput")
    items.sort(key=lambda item: hasattr(item.module, "start_at_collection") != under_xdist)


def pytest_collection_finish(session: pytest.Session) -> None:
    if session.config.option.collectonly or hasattr(session.config, "workerinput"):
        return  # (each xdist worker collects every test; the test starts its own work there)
    modules = {item.module for item in session.items if hasattr(item.module, "start_at_collection")}
    for module in modules:
        module.start_at_collection()
