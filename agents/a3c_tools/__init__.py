"""The tools around the agent scripts, apart from the algorithms (as CleanRL keeps its tools in
`cleanrl_utils`). Each is a module run with `python -m a3c_tools.<tool>` from a clone of the
repository (installed with `pip install -e "./agents[tools]"`), with `--help`:

- `sweep`: a script at sampled flags, many runs, locally or on a Ray cluster, resumable;
- `plot_sweep`, `plot_evaluations`: the thesis-style figures of a sweep, a run's learning curve;
- `thesis_figures`: a thesis Catch figure's lines, as run, through `sweep` and `plot_sweep`
  (its figures are data: thesis_figures.toml);
- `atari_figures`: the thesis's Atari figures (6.9, 6.10, 7.8) over seeds, through `sweep`, drawn
  with a shaded band (its figures are data: atari_figures.toml);
  it and `thesis_figures` share `figure_sweeps` (the figures files' checks, the sweeps in
  rounds, the command line);
- `thesis_claims`: the claims page (docs/claims.md) and its forest plot from the committed
  results (thesis_claims.toml);
- `compare`: two scripts, or one with two flag sets, at the same learning rates and run seeds:
  the paired effect, its 95% interval, a verdict and a figure (docs/testing-your-idea.md); it
  and `thesis_claims` share `paired` (the pairing, the t interval, the verdict rule);
- `future_work_summary`, `future_work_initial_policy`, `future_work_trained_scale`,
  `future_work_growth`: the analyses of chapter 8's ideas on Catch (results/future_work_catch,
  the folder `future_work_runs` reads from their command line);
- `training_scalars`: a run's TensorBoard training scalars by 1M steps;
- `record_play`: a checkpoint's agent playing one episode, as an animated GIF;
- `convert_checkpoint`: a checkpoint from before safe loading, that its owner trusts, into the
  safe form (docs/runs.md);
- `atari_report`: the Atari lines across seeds and games (the IQM, means with t intervals over
  seeds, a performance profile drawn with rliable; its lines are data: atari_report.toml);
- `campaign`: a fixed plan of sweeps run in its order over sessions, resumable, with its
  progress (results/campaign/plan.toml).

`batched` is the sweep's side of the batched backend (`--backend batched`: its runs checked
before anything runs, and the sweep's runs as batches of the runtime's a3c_runtime.batched,
docs/reproducing.md). Shared by the tools: `read_toml` (their data files, one line on a bad
one), `parsed_flags` (a script's flags, tyro's error on one line) and `tool_parser` (a tool's
command line, named as it is run).

Nothing runs at import; the tools' own dependencies (matplotlib, scipy, rliable) are the `tools`
extra.
"""

from __future__ import annotations

import argparse
import importlib.util
import os
import sys
from collections.abc import Callable
from pathlib import Path
from types import ModuleType
from typing import Any, NoReturn

ROOT = Path(__file__).resolve().parents[2]  # the repository: the tools work on a clone
AGENTS = ROOT / "agents"
# the Atari games' random and human scores and atari_report's lines (read by atari_report and
# paired: here, so that neither imports the other)
ATARI_REPORT_CONFIG = Path(__file__).with_name("atari_report.toml")


def results_folder(value: str, root: Path = ROOT) -> Path:
    """A folder a plan or table names (relative to the clone, `root`, or absolute): it must lie
    inside the clone's results/ (the runs a tool reads or writes are the repository's), else
    ValueError naming it."""
    if not (root / value).resolve().is_relative_to((root / "results").resolve()):
        raise ValueError(f"{value!r} is not a folder under results/")
    return Path(value)


def agent_script(value: str) -> Path:
    """A script a plan names (relative to the clone or absolute): it must be one of the clone's
    agent scripts (agent_scripts()), else ValueError naming the valid ones."""
    resolved = (ROOT / value).resolve()
    agents = AGENTS.resolve()
    if not (
        resolved.is_relative_to(agents)
        and resolved.relative_to(agents).as_posix() in agent_scripts()
    ):
        raise ValueError(
            f"no agent script {value}; valid: agents/a3c_*.py, agents/future_work/a3c_*.py"
        )
    return Path(value)


def agent_scripts() -> set[str]:
    """The agent scripts of this clone, as their checkpoints name them (relative to agents/):
    agents/a3c_*.py and agents/future_work/a3c_*.py."""
    found = [*AGENTS.glob("a3c_*.py"), *(AGENTS / "future_work").glob("a3c_*.py")]
    return {path.relative_to(AGENTS).as_posix() for path in found}


def load_script(path: Path | str) -> ModuleType:
    """Import an agent script (agents/a3c_*.py, agents/future_work/a3c_*.py) as a module named
    after its file, once per process: the scripts are run by path, not installed."""
    path = Path(path)
    if path.stem in sys.modules:
        return sys.modules[path.stem]
    spec = importlib.util.spec_from_file_location(path.stem, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[path.stem] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


def read_toml(path: Path) -> dict:
    """A TOML file's table, or ValueError in one line naming the file: unreadable, not UTF-8,
    not TOML, or nested past the parser's depth (RecursionError, not a data file)."""
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    try:
        return tomllib.loads(Path(path).read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:  # TOMLDecodeError, UnicodeDecodeError
        raise ValueError(f"{path}: {error}") from None
    except RecursionError:
        raise ValueError(f"{path}: TOML nested too deep to read") from None


def tyro_message(text: str) -> str:
    """The message of a tyro error on one line: the first section of its (last) box, drawn in
    box-drawing characters on a terminal and in dashes elsewhere; else the last line that is not
    a rule ('' when there is none)."""
    lines = [line.strip().strip("│").strip() for line in text.splitlines()]
    rules = [i for i, line in enumerate(lines)
             if line.startswith("╭") or (line and set(line) <= set("-─━╰╯ "))]  # fmt: skip
    tops = [i for i in rules if lines[i].startswith("╭")]
    start = tops[-1] if tops else (rules[0] if rules else None)
    ends = [i for i in rules if start is not None and i > start]
    if ends and (message := " ".join(line for line in lines[start + 1 : ends[0]] if line)):
        return message
    said = [line for i, line in enumerate(lines) if line and i not in rules]
    return said[-1] if said else ""


def parsed_flags(args_type: type, flags: list[str], prog: str | None = None) -> Any:
    """args_type parsed from flags by tyro, quietly, or ValueError with tyro's message on one
    line (tyro_message)."""
    import contextlib
    import io

    import tyro

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            return tyro.cli(args_type, args=flags, prog=prog)
    except SystemExit:
        raise ValueError(tyro_message(err.getvalue()) or "see --help") from None


def tool_parser(tool: str, description: str, **kw: Any) -> argparse.ArgumentParser:
    """The command line of `python -m a3c_tools.<tool>`, with its description (and argparse's
    other arguments, `kw`)."""
    return argparse.ArgumentParser(
        prog=f"python -m a3c_tools.{tool}", description=description, **kw
    )


def run_main(main: Callable[[], int | None]) -> NoReturn:
    """A tool's `python -m` entry: exit with main()'s code. A reader that closes stdout early
    (`... --dry-run | head`) ends the tool with exit code 1 and no BrokenPipeError traceback
    (Python's recipe, in the signal module's documentation)."""
    try:
        try:
            code = main()
        finally:
            sys.stdout.flush()  # here, where a closed pipe can still be caught
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # so that the flush at exit cannot fail again
        sys.exit(1)
    sys.exit(code)
