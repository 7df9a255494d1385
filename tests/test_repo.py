"""Repository-level promises: the README's commands, lint, and catch_env without torch."""

import importlib.util
import re
import shutil
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

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
    command = readme_commands()[1]
    assert f"{command} || exit 1" in ci_lines  # a failed install or test ends CI


def test_catch_env_does_not_import_torch():
    code = (
        "import sys, catch_env, catch_env.wrappers, catch_env.play, catch_env.rendering; "
        "assert 'torch' not in sys.modules, 'catch_env imported torch'"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


def test_catch_env_works_without_torch_and_its_torch_env_says_what_it_needs():
    """With torch absent (blocked in sys.modules), Catch-v0 makes, resets and steps, and only
    catch_env.torch_catch fails, in one line naming the extra to install."""
    code = (
        "import sys; sys.modules['torch'] = None\n"
        "import gymnasium as gym, catch_env\n"
        "env = gym.make('Catch-v0'); env.reset(seed=0); env.step(0)\n"
        "try:\n    import catch_env.torch_catch\nexcept ImportError as e:\n    print(e)\n"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == (
        'catch_env.torch_catch needs torch: pip install "catch-env[torch]" (or torch)'
    )


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


README_MAX_LINES = 200
DOCS = ROOT / "docs"
# The thesis notes are kept as written (they quote the thesis code's own dates).
DOCS_AS_WRITTEN = {"thesis-notes.md", "thesis-figures-as-run.md"}
# A measurement's date and conditions belong in its results folder's COMMAND.txt.
DATED_NARRATIVE = re.compile(
    r"\b20[2-9]\d-\d\d-\d\d\b|\b\d\d:\d\d UTC\b|\bthis (?:morning|afternoon|evening)\b"
    r"|\bfast day\b|\btoday(?:'s)?\b|\b(?:since |before )?issue \d+\b",
    re.IGNORECASE,
)


def docs_pages() -> list[Path]:
    return sorted(path for path in DOCS.rglob("*.md"))


def test_readme_is_a_short_front_door():
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines"


@pytest.mark.parametrize(
    "page",
    [ROOT / "README.md"] + [path for path in docs_pages() if path.name not in DOCS_AS_WRITTEN],
    ids=lambda path: str(path.relative_to(ROOT)),
)
def test_no_dated_narrative(page):
    found = [
        f"line {number}: {match.group(0)!r}"
        for number, line in enumerate(page.read_text().splitlines(), 1)
        for match in DATED_NARRATIVE.finditer(line)
    ]
    assert not found, (
        f"{page.relative_to(ROOT)}: dated narrative (move it to a COMMAND.txt): {found}"
    )


def relative_links(text: str) -> list[str]:
    """The targets of a Markdown page's links and images that point into the repository
    (no scheme, not a bare anchor), without their anchors."""
    targets = re.findall(r"!?\[[^\]]*\]\(([^)\s]+)\)", text)
    return [
        target.split("#")[0]
        for target in targets
        if not re.match(r"[a-z][a-z0-9+.-]*:", target) and not target.startswith("#")
    ]


@pytest.mark.parametrize("page", docs_pages(), ids=lambda path: str(path.relative_to(ROOT)))
def test_docs_links_exist(page):
    """Every relative link and image of a docs page (learning curves and COMMAND.txt files in
    results/ among them) names a file of the repository, as mkdocs build --strict checks."""
    missing = [
        target
        for target in relative_links(page.read_text())
        if not (page.parent / target).resolve().exists()
    ]
    assert not missing, f"{page.relative_to(ROOT)} links to files that are not here: {missing}"


def test_readme_links_to_docs_that_exist():
    missing = [
        target
        for target in relative_links((ROOT / "README.md").read_text())
        if not (ROOT / target).exists()
    ]
    assert not missing, f"the README links to files that are not here: {missing}"


def test_every_docs_page_is_in_the_mkdocs_nav():
    nav = set(re.findall(r":\s*([\w./-]+\.md)\s*$", (ROOT / "mkdocs.yml").read_text(), re.M))
    pages = {path.relative_to(DOCS).as_posix() for path in docs_pages()}
    assert pages - nav == set(), f"docs pages missing from mkdocs.yml's nav: {pages - nav}"
    assert nav - pages == set(), f"mkdocs.yml's nav names pages that are not here: {nav - pages}"


def load_readme_opening_hook():
    spec = importlib.util.spec_from_file_location(
        "readme_opening", ROOT / "docs" / "hooks" / "readme_opening.py"
    )
    hook = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(hook)
    return hook


def test_the_site_home_opens_with_the_readmes_opening_linked_from_docs():
    """docs/index.md says the README's opening once, through the hook that mkdocs.yml names: the
    hook puts it in the marker's place, whole fences and all, with every link rewritten to name
    a file from docs/."""
    hook = load_readme_opening_hook()
    mkdocs_yml = (ROOT / "mkdocs.yml").read_text()
    assert re.search(r"^hooks:\n(  - .*\n)*  - docs/hooks/readme_opening\.py$", mkdocs_yml, re.M)
    config = SimpleNamespace(config_file_path=str(ROOT / "mkdocs.yml"))
    home = hook.on_page_markdown((ROOT / "docs" / "index.md").read_text(), None, config, None)
    assert hook.MARKER not in home and readme_commands()[0] in home
    opening = hook.readme_opening((ROOT / "README.md").read_text())
    assert opening in home and "\n## " not in opening and opening.count("```") % 2 == 0
    links = relative_links(opening)
    assert links and all(not link.startswith(("docs/", "results/")) for link in links)
    missing = [link for link in links if not (ROOT / "docs" / link).resolve().exists()]
    assert not missing, f"the home page's opening links to files that are not here: {missing}"


def test_the_readmes_opening_ends_at_a_heading_outside_code_blocks():
    hook = load_readme_opening_hook()
    readme = (
        "# Title\n\n```bash\n## a shell comment\nls\n```\n\nSee [it](docs/a.md).\n\n## Next\nrest\n"
    )
    assert hook.readme_opening(readme) == "```bash\n## a shell comment\nls\n```\n\nSee [it](a.md)."
    with pytest.raises(ValueError, match="title"):
        hook.readme_opening("no title\n")
