"""Shared helpers of the agent tests: load a script by path, run it as a subprocess, tiny runs.

The agent scripts import agents/a3c_runtime.py as a sibling module (the script's folder is on
sys.path when it runs by path); the agents folder goes on sys.path here so that scripts loaded
with importlib find it too."""

from __future__ import annotations

import csv
import importlib.util
import subprocess
import sys
from pathlib import Path
from types import ModuleType

ROOT = Path(__file__).resolve().parents[1]
AGENTS = ROOT / "agents"
if str(AGENTS) not in sys.path:
    sys.path.insert(0, str(AGENTS))

SCRIPTS = ("a3c_ff", "a3c_lws", "a3c_ss", "a3c_ww", "a3c_lstm", "a3c_lpq", "a3c_glpq")
# a tiny run: 2 workers, 5 evaluation episodes, a progress line every second
TINY = ["--num-workers", "2", "--eval-episodes", "5", "--log-interval", "1"]


def load_script(name: str) -> ModuleType:
    """Import agents/<name>.py as a module named after its file (once per test session)."""
    if name in sys.modules:
        return sys.modules[name]
    spec = importlib.util.spec_from_file_location(name, AGENTS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def run_script(name: str, *flags: str, timeout: float = 120) -> subprocess.CompletedProcess:
    """Run agents/<name>.py by path, as a user does, from the repository root."""
    return subprocess.run(
        [sys.executable, str(AGENTS / f"{name}.py"), *flags],
        capture_output=True,
        text=True,
        timeout=timeout,
        cwd=ROOT,
    )


def read_evaluations(run_dir: Path) -> list[dict]:
    with open(run_dir / "evaluations.csv") as f:
        return list(csv.DictReader(f))


def evaluation_steps(run_dir: Path) -> list[int]:
    return [int(row["global_step"]) for row in read_evaluations(run_dir)]
