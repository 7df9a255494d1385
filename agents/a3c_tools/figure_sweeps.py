"""What the two figure runners share: thesis_figures (the Catch figures, learning-rate sweeps) and
atari_figures (the Atari figures, curves over seeds).

Each reads a TOML file of figures and their lines (an agent script and its flags), checked here
table by table; runs every line as one a3c_tools.sweep, so that the same command again resumes
(sweep.py skips the runs in a line's results.csv and resumes a cut-off one from its
checkpoint), in rounds, so that a stopped figure has covered its lines evenly; and then draws.
A line that several figures show names the first with `same_as` and is swept once, in that
line's folder. What differs stays in each runner: what a line sweeps (learning rates, or seeds
of one configuration) and how a figure is drawn.
"""

from __future__ import annotations

import argparse
import os
import shlex
import signal
import subprocess
import sys
import threading
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

from a3c_tools import AGENTS, read_toml

SWEEP = ["-m", "a3c_tools.sweep"]  # the tools, run with this interpreter


def display(path: Path) -> str:
    """A path as the commands show it: relative to the working directory when inside it."""
    relative = os.path.relpath(path)
    return relative if not relative.startswith("..") else str(path)


def plural(count: int, noun: str) -> str:
    return f"{count} {noun}{'s' * (count != 1)}"


# ------------------------------------------------------------------------------------------------
# The data files
# ------------------------------------------------------------------------------------------------
class DataError(ValueError):
    """A malformed data file: the message names the figure and line, and the problem."""


TYPES = {str: "a string", list: "a list", dict: "a table", int: "an integer"}
MAY_BE_EMPTY = ("flags",)  # "" is the script's defaults


def table(entry: object, keys: dict[str, Any], kind: str, where: str) -> dict:
    """A table of a data file, checked against keys (a key's type; "?" ends an optional key's
    name): no unknown key, every required key there and, but for flags, not empty. Its strings
    come back with every run of whitespace (line breaks included) as one space."""
    wanted = {key.rstrip("?"): (type_, key[-1] != "?") for key, type_ in keys.items()}
    if not isinstance(entry, dict):
        raise DataError(f"{where}: expected a table, got {entry!r}")
    for key, value in entry.items():
        if key not in wanted:
            raise DataError(f"{where}: unknown key {key!r} (a {kind} has {', '.join(wanted)})")
        type_ = wanted[key][0]
        if not isinstance(value, type_) or isinstance(value, bool):
            name = TYPES.get(type_, "a number")
            raise DataError(f"{where}: {key} must be {name}, got {value!r}")
    for key, (_, required) in wanted.items():
        empty = entry.get(key) in ("", [], {}) and key not in MAY_BE_EMPTY
        if required and (key not in entry or empty):
            raise DataError(f"{where}: no {key}")
    return {key: " ".join(v.split()) if isinstance(v, str) else v for key, v in entry.items()}


def read_file(path: Path, keys: dict[str, Any]) -> tuple[str, dict]:
    """A data file's name as messages give it, and its top-level table, checked."""
    file = display(path)
    try:
        data = read_toml(path)
    except ValueError as error:
        raise DataError(f"{file}: {str(error).removeprefix(f'{path}: ')}") from None
    return file, table(data, keys, "file", file)


def words(text: str, where: str) -> list[str]:
    try:
        return shlex.split(text)
    except ValueError as error:
        raise DataError(f"{where}: flags are not shell words ({error}): {text}") from None


def check_line(line: dict, where: str) -> None:
    """A line's script is one in agents/, its slug a plain folder name."""
    if Path(line["script"]).name != line["script"] or not (AGENTS / line["script"]).is_file():
        raise DataError(f"{where}: script {line['script']!r} is not in {display(AGENTS)}/")
    if line["slug"] != Path(line["slug"]).name or " " in line["slug"]:
        raise DataError(f"{where}: slug {line['slug']!r} is not a plain folder name")


def check_unique(values: list[str], what: str, where: str) -> None:
    for value in values:
        if values.count(value) > 1:
            raise DataError(f"{where}: two {what} {value!r}")


def check_same_as(
    figures: Iterable[Any], file: str, differs: Callable[[Any, Any, Any, Any], str | None]
) -> None:
    """Every line's same_as names FIG/SLUG, a line of the file with runs of its own (not itself
    same_as another), of the same configuration: differs(figure, line, owner, target), where
    owner is target's figure, says what is not the same (None: nothing)."""
    lines = {f"{fig.id}/{line.slug}": (fig, line) for fig in figures for line in fig.lines}
    for figure in figures:
        for line in figure.lines:
            if not line.same_as:
                continue
            where = f"{file}: figure {figure.id}, line {line.label!r}: same_as {line.same_as!r}"
            if line.same_as not in lines:
                raise DataError(f"{where} is no FIG/SLUG of this file")
            owner, target = lines[line.same_as]
            if target.same_as:
                raise DataError(f"{where} is itself same_as {target.same_as!r}; name that line")
            problem = differs(figure, line, owner, target)
            if problem:
                raise DataError(f"{where} {problem}")


def run_as(figure: Any, line: Any, by_id: Callable[[str], Any]) -> tuple[Any, Any]:
    """The figure and line whose sweep a line's runs are: itself, or its same_as line."""
    if not line.same_as:
        return figure, line
    fig, slug = line.same_as.split("/")
    return by_id(fig), next(other for other in by_id(fig).lines if other.slug == slug)


def figure_id(text: str, ids: Iterable[str]) -> str | None:
    """The figure id for fig7.6, Fig7.6, 7.6, figure 7.6, figa.1, A.1 ...; None when there is no
    such figure."""
    key = text.strip().lower()
    for prefix in ("figure", "fig"):
        if key.startswith(prefix):
            key = key[len(prefix) :].lstrip(" ._-")
            break
    return next((id for id in ids if id.lower() == f"fig{key}"), None)


# ------------------------------------------------------------------------------------------------
# Running the sweeps
# ------------------------------------------------------------------------------------------------
def execute(command: list[str], capture: bool = False) -> tuple[int, str]:
    """Run a tool of this package with this interpreter: its exit code, and its stdout when
    captured (echoed all the same). A Ctrl-C reaches the tool too (same process group), and a
    SIGTERM to this process is passed on to it: either way this waits for it to stop its runs
    cleanly (sweep.py exits 130) rather than dying and leaving it behind."""
    sys.stdout.flush()
    process = subprocess.Popen(
        [sys.executable, *command], stdout=subprocess.PIPE if capture else None, text=True
    )
    passing_on = threading.current_thread() is threading.main_thread()  # signal's rule
    if passing_on:
        previous = signal.signal(signal.SIGTERM, lambda *_: process.send_signal(signal.SIGTERM))
    try:
        while True:
            try:
                stdout = process.communicate()[0]  # None when not captured
                break
            except KeyboardInterrupt:
                continue
    finally:
        if passing_on:
            signal.signal(signal.SIGTERM, previous)
    if capture:
        sys.stdout.write(stdout)
        sys.stdout.flush()
    return process.returncode, stdout or ""


@dataclass(frozen=True)
class Sweep:
    """One line's sweep, as a figure runs it."""

    name: str  # FIG [GAME] LABEL
    folder: Path  # its runs' folder: a line that figures share is swept once a round
    command: Callable[[int], list[str]]  # sweep.py's command for so many runs
    shared: str = ""  # what the progress line says of a line whose runs are another's


def run_sweeps(sweeps: list[Sweep], rounds: list[int], noun: str, draw: Callable[[], Any]) -> int:
    """Sweep every line to each round's number of runs in turn, then draw. The exit code: 2 or
    130 as a sweep's (a folder holding another configuration; interrupted), which stops it; 1
    when some line's every run failed; 3 when a run was in use elsewhere (resumed by hand: the
    same command picks it up once it is free); else 0."""
    failed, in_use = [], []
    for target in rounds:
        swept: set[Path] = set()
        for sweep in sweeps:
            print(f"== {sweep.name}{sweep.shared}: {plural(target, noun)}", flush=True)
            if sweep.folder in swept:
                continue
            swept.add(sweep.folder)
            code, _ = execute(sweep.command(target))
            if code in (2, 130):
                return code
            if code == 1 and target == rounds[-1]:
                failed.append(sweep.name)
            if code == 3:  # sweep.py's IN_USE_EXIT
                in_use.append(sweep.name)
    draw()
    if failed:
        print(f"every run failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    if in_use:
        print(f"a run in use elsewhere, not yet done: {', '.join(in_use)}; the same command "
              "goes on once it is free", file=sys.stderr)  # fmt: skip
        return 3
    return 0


def print_dry_run(
    figures: Iterable[Any], commands: Callable[[Any], list[list[str]]], repeat: str
) -> None:
    """A dry run: each figure's commands under its caption, each once; a repeat (the sweep of a
    line that figures share) is a comment, `# {repeat} COMMAND`."""
    printed: set[str] = set()
    for figure in figures:
        print(f"# {figure.id}: {figure.caption}")
        for command in commands(figure):
            text = shlex.join(["python", *command])
            print(f"# {repeat} {text}" if text in printed else text)
            printed.add(text)


# ------------------------------------------------------------------------------------------------
# Command line
# ------------------------------------------------------------------------------------------------
class Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        """One line, exit 2 (argparse's own error prints the usage too)."""
        print(f"{self.prog}: error: {message} (see --help)", file=sys.stderr)
        raise SystemExit(2)


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def figure_parser(
    tool: str, usage: str, description: str, ids: tuple[str, ...], printed: str
) -> Parser:
    """A runner's command line, with what both take first: the figures, --list, --dry-run (which
    prints the `printed` commands)."""
    parser = Parser(prog=f"python -m a3c_tools.{tool}", usage=usage, description=description)
    parser.add_argument(
        "figures", nargs="*", metavar="FIG", help=f"figure ids ({', '.join(ids)}) or all"
    )
    parser.add_argument("--list", action="store_true", help="print the figures, lines and flags")
    parser.add_argument("--dry-run", action="store_true", help=f"print {printed}, run nothing")
    return parser


def add_backend_arguments(
    parser: Parser, batched: bool = False, default: str | None = "local", concurrent: bool = False
) -> None:
    """Where the sweeps run: sweep.py's --backend (its default None where a tool tells a given
    flag from a default), --address and --cpus; for Catch lines, `batched`: --backend batched
    and its --device; `concurrent`: --max-concurrent."""
    backends = ["local", "ray", "batched"] if batched else ["local", "ray"]
    parser.add_argument("--backend", choices=backends, default=default,
                        help="where the sweeps run (default local; batched: each line's runs "
                        "as one program on --device, one worker a run)")  # fmt: skip
    if batched:
        parser.add_argument("--device", choices=["cpu", "cuda"], default=None,
                            help="with --backend batched: cpu or cuda (default cpu)")  # fmt: skip
    parser.add_argument("--address", default=None, help="with --backend ray: a running cluster")
    parser.add_argument("--cpus", type=positive_int, default=None, help="passed to sweep.py")
    if concurrent:
        parser.add_argument("--max-concurrent", type=positive_int, default=None,
                            help="passed to sweep.py")  # fmt: skip


def chosen_figures(parser: Parser, texts: list[str], ids: tuple[str, ...]) -> list[str]:
    """The figure ids named on the command line ("all": every one), each once."""
    chosen = []
    for text in texts:
        if text.lower() == "all":
            chosen += ids
            continue
        found = figure_id(text, ids)
        if found is None:
            parser.error(f"unknown figure {text!r}; valid: {', '.join(ids)}, all")
        chosen.append(found)
    return list(dict.fromkeys(chosen))


# what a dry run may leave out, and the word its commands print instead
PLACEHOLDERS = {"out": "OUT", "runs": "RUNS", "seeds": "SEEDS", "steps": "STEPS"}


def check_run_options(
    parser: Parser, options: argparse.Namespace, ids: tuple[str, ...], needed: list[str]
) -> None:
    """A command that runs or draws names a figure, the options it needs (a dry run needs none:
    it prints a placeholder for each, PLACEHOLDERS), and --backend ray for --address."""
    if not options.ids:
        parser.error(f"name a figure: {', '.join(ids)}, all (or --list)")
    needed = [] if options.dry_run else needed
    missing = [f"--{flag}" for flag in needed if getattr(options, flag) is None]
    if missing:
        parser.error(f"the following arguments are required: {', '.join(missing)}")
    if options.address and options.backend != "ray":
        parser.error("--address needs --backend ray")
    if getattr(options, "device", None) and options.backend != "batched":
        parser.error("--device needs --backend batched")


def data_or_exit(read: Callable[[], Any], tool: str) -> int | None:
    """Read a runner's data file: None when it is well formed, else 2 after its one line."""
    try:
        read()
    except DataError as error:
        print(f"{tool}: error: {error}", file=sys.stderr)
        return 2
    return None


def run_command(
    options: argparse.Namespace,
    figures: list[Any],
    listing: Callable[[list[Any]], str],
    dry_run: Callable[[Any, argparse.Namespace], list[list[str]]],
    repeat: str,
    run: Callable[[list[Any], argparse.Namespace], int],
) -> int:
    """What a runner does with its command line: --list prints the figures (listing), --dry-run
    each figure's commands (dry_run; `repeat` marks a shared sweep's), else run runs them."""
    if options.list:
        print(listing(figures))
        return 0
    if options.dry_run:
        missing = {flag: text for flag, text in PLACEHOLDERS.items()
                   if getattr(options, flag, 0) is None}  # fmt: skip
        for flag, text in missing.items():
            setattr(options, flag, text)
        if missing:
            print("# " + ", ".join(f"{text} stands for --{flag}" for flag, text in missing.items()))
        print_dry_run(figures, lambda figure: dry_run(figure, options), repeat)
        return 0
    return run(figures, options)
