"""Repository-level promises: the README's commands, lint, and catch_env without torch."""

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def readme_commands() -> list[str]:
    """The shell commands in the README's first code block."""
    readme = (ROOT / "README.md").read_text()
    block = re.search(r"```(?:bash|sh)\n(.*?)```", readme, re.DOTALL)
    assert block, "README.md must open with a bash code block holding the two commands"
    return [line for line in block.group(1).splitlines() if line and not line.startswith("#")]


def test_readme_starts_with_the_main_job_and_test_commands():
    main_job, tests = readme_commands()
    assert "pip install" in main_job and "agents/a3c_ff.py" in main_job
    assert "pip install" in tests and "pytest" in tests


def test_ci_runs_the_readme_test_command():
    ci_lines = (ROOT / ".ci" / "run").read_text().splitlines()
    assert readme_commands()[1] in ci_lines


def test_catch_env_does_not_import_torch():
    code = (
        "import sys, catch_env, catch_env.wrappers, catch_env.play, catch_env.rendering; "
        "assert 'torch' not in sys.modules, 'catch_env imported torch'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.skipif(shutil.which("ruff") is None, reason="ruff is in the [test] extra")
@pytest.mark.parametrize("command", [["ruff", "check", "."], ["ruff", "format", "--check", "."]])
def test_ruff_clean(command):
    result = subprocess.run(command, cwd=ROOT, capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


def test_every_result_has_its_command():
    """The standard: a result counts only with the command that made it."""
    folders = [path for path in (ROOT / "results").iterdir() if path.is_dir()]
    assert folders
    missing = [path.name for path in folders if not (path / "COMMAND.txt").is_file()]
    assert not missing, f"results folders without COMMAND.txt: {missing}"


def test_readme_links_to_results_that_exist():
    """Every image and every `results/...` path the README names is in the repository (a shell
    brace such as results/x_{a,b}/ names each of its expansions)."""
    readme = (ROOT / "README.md").read_text()
    images = re.findall(r"!\[[^\]]*\]\(([^)]+)\)", readme)
    paths = []
    for path in re.findall(r"`(results/[\w./{},-]+)", readme):
        brace = re.search(r"\{([^}]*)\}", path)
        alternatives = brace.group(1).split(",") if brace else [""]
        paths += [path.replace(brace.group(0), a) if brace else path for a in alternatives]
    assert images and paths
    missing = [path for path in images + paths if not (ROOT / path.rstrip("/.")).exists()]
    assert not missing, f"the README names files that are not here: {missing}"
