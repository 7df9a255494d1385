"""Every command in a fenced bash/sh/console block of README.md and docs/**/*.md is a current
one: its program exists and its flags parse, in process and without running anything. An agent
script's flags parse against its tyro Args (and resolve_defaults' checks); a tool's
(`python -m a3c_tools.X`, `catch-play`, `python benchmarks/X.py`) against its own argparse
parser, which is stopped right after parsing; `pip install` names extras that exist; other
programs name files that exist. Placeholders (`runs/<run>/...`, `[OPTIONAL ...]`) parse as
text."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import io
import re
import shlex
import shutil
import sys
from pathlib import Path

import a3c_runtime as runtime
import pytest
import tyro
from conftest import ROOT, SCRIPT_PATHS, load_script

try:
    import tomllib
except ImportError:  # Python 3.10: the tools' backport
    import tomli as tomllib

PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
SHELLS = ("bash", "sh", "shell", "console")
# programs whose arguments are files of the repository (or files an earlier command makes)
FILE_PROGRAMS = {"bash", "cp", "diff"}


def commands(page: Path) -> list[list[str]]:
    """The commands of a page's shell blocks: continuation lines joined, comments and a console
    block's `$ ` prompts dropped, `a && b` split in two, leading VAR=value assignments dropped."""
    found = []
    text = page.read_text()
    for lang, body in re.findall(r"^```(\w*)\n(.*?)^```", text, re.S | re.M):
        if lang not in SHELLS:
            continue
        lines = body.replace("\\\n", " ").splitlines()
        if lang == "console":  # only the prompted lines are commands
            lines = [line[2:] for line in lines if line.startswith("$ ")]
        for line in lines:
            words = shlex.split(line, comments=True)
            while words:
                cut = words.index("&&") if "&&" in words else len(words)
                command, words = words[:cut], words[cut + 1 :]
                while command and re.fullmatch(r"[A-Z_]+=\S*", command[0]):
                    command = command[1:]
                redirect = [i for i, w in enumerate(command) if w in (">", ">>", "2>", "|")]
                command = command[: redirect[0]] if redirect else command  # the output's file
                if command:
                    found.append(command)
    return found


def without_optional(argv: list[str]) -> list[str]:
    """argv without a usage synopsis's optional parts, `[SCRIPT ...]`."""
    kept, depth = [], 0
    for word in argv:
        if word.startswith("["):
            depth += 1
        if not depth:
            kept.append(word)
        if word.endswith("]") and depth:
            depth -= 1
    return kept


CASES = [
    pytest.param(page, argv, id=f"{page.relative_to(ROOT)}: {shlex.join(argv)}"[:150])
    for page in PAGES
    for argv in commands(page)
]


class Parsed(Exception):
    """Raised by the patched ArgumentParser.parse_args: the arguments parsed; nothing runs."""


@contextlib.contextmanager
def parse_only(monkeypatch: pytest.MonkeyPatch, argv0: str, argv: list[str]):
    """A tool's main() with its argparse parser stopped right after parsing argv; a usage
    error (exit 2) fails the test with the parser's message, --help (exit 0) passes."""
    parse_args = argparse.ArgumentParser.parse_args

    def parse_then_stop(self, args=None, namespace=None):
        raise Parsed(parse_args(self, args, namespace))

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
    monkeypatch.setattr(sys, "argv", [argv0, *argv])
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
        try:
            yield
        except Parsed:
            return
        except SystemExit as e:
            assert e.code in (0, None), f"{argv0} {shlex.join(argv)}: {stderr.getvalue()}"
            return
    pytest.fail(f"{argv0} {shlex.join(argv)} ran without parsing its arguments")


def check_agent(path: str, argv: list[str]) -> None:
    name = Path(path).stem
    assert SCRIPT_PATHS.get(name) == ROOT / path, f"no agent script {path}"
    module = load_script(name)
    stderr = io.StringIO()
    with contextlib.redirect_stderr(stderr), contextlib.redirect_stdout(io.StringIO()):
        try:
            args = tyro.cli(module.Args, args=argv)
        except SystemExit as e:  # --help exits 0
            assert e.code == 0, f"{path} {shlex.join(argv)}: {stderr.getvalue()}"
            return
    try:
        runtime.resolve_defaults(args)
    except runtime.UsageError as e:
        pytest.fail(f"{path} {shlex.join(argv)}: {e}")


def check_pip(argv: list[str]) -> None:
    """`pip install [pins] -e "PATH[extra,...]"`: each PATH a project, each extra one of its."""
    assert argv[:2] == ["pip", "install"], argv
    for word in argv[2:]:
        if word == "-e" or re.fullmatch(r"[\w-]+==[\w.]+", word):
            continue
        folder, extras = re.fullmatch(r"([^\[]+)(?:\[([\w,-]+)\])?", word).groups()
        project = tomllib.loads((ROOT / folder / "pyproject.toml").read_text())["project"]
        for extra in (extras or "").split(",") if extras else []:
            assert extra in project["optional-dependencies"], f"{word}: no extra {extra!r}"


def check_python(argv: list[str], monkeypatch: pytest.MonkeyPatch) -> None:
    if argv[0] == "-m":
        module, rest = argv[1], argv[2:]
        if module == "pytest":
            return
        assert importlib.util.find_spec(module) is not None, f"no module {module}"
        tool = importlib.import_module(module)
        with parse_only(monkeypatch, module, rest):
            tool.main(rest)
        return
    path, rest = argv[0], argv[1:]
    if path.startswith("agents/"):
        check_agent(path, rest)
        return
    assert path.startswith("benchmarks/") and (ROOT / path).is_file(), f"no program {path}"
    spec = importlib.util.spec_from_file_location(f"doc_{Path(path).stem}", ROOT / path)
    benchmark = importlib.util.module_from_spec(spec)
    monkeypatch.setitem(sys.modules, spec.name, benchmark)
    spec.loader.exec_module(benchmark)
    with parse_only(monkeypatch, path, rest):
        benchmark.main()


@pytest.mark.parametrize(("page", "argv"), CASES)
def test_each_documented_command_exists_and_its_flags_parse(page, argv, monkeypatch):
    argv = without_optional(argv)
    program, rest = argv[0], argv[1:]
    if program == "python":
        check_python(rest, monkeypatch)
    elif program == "pip":
        check_pip(argv)
    elif program == "catch-play":
        from catch_env import play

        project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
        assert project["scripts"]["catch-play"] == "catch_env.play:main"
        with parse_only(monkeypatch, program, rest):
            play.main(rest)
    elif program == "tensorboard":
        assert importlib.util.find_spec("tensorboard") is not None
        assert rest[:1] == ["--logdir"], rest
    elif program in FILE_PROGRAMS:
        assert shutil.which(program), f"no program {program}"
        made = {c[-1] for c in commands(page) if c[0] == "cp"}  # what an earlier cp makes
        files = [w for w in rest if not w.startswith("-")]
        files = files[:1] if program == "bash" else files[:-1] if program == "cp" else files
        for word in files:  # bash: its script (the rest are the script's); cp: the source
            if word not in made:
                assert (ROOT / word).is_file(), f"{shlex.join(argv)}: no file {word}"
    else:
        pytest.fail(f"{page.name}: unknown program {program!r} in {shlex.join(argv)}")


def test_the_commands_are_found():
    """The collection itself: continuation lines, comments, && and prompts."""
    assert len(CASES) > 50
    readme = commands(ROOT / "README.md")
    assert ["python", "agents/a3c_ff.py", "--help"] in readme
    assert any(c[:3] == ["python", "-m", "a3c_tools.sweep"] and c[-1] == "12500" for c in readme)
    assert ["python", "-m", "pytest", "-n", "auto"] in readme


def test_a_stale_command_fails(monkeypatch, tmp_path):
    """What the test refuses: a moved script, an unknown flag, an extra that does not exist."""
    page = tmp_path / "page.md"
    page.write_text(
        "```bash\npython agents/sweep.py --out x\npython agents/a3c_ff.py --no-such-flag 1\n"
        "diff agents/a3c_ff.py agents/no_such.py\n"
        'python -m a3c_tools.plot_sweep a.csv --no-such-flag\npip install -e ".[nope]"\n```\n'
    )
    for argv in commands(page):
        with pytest.raises((AssertionError, pytest.fail.Exception)):
            test_each_documented_command_exists_and_its_flags_parse(page, argv, monkeypatch)
