"""Both distributions as a package index shows them: license, links, classifiers, readme."""

from __future__ import annotations

import importlib.metadata
import re
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path
from typing import Any

import pytest

# Python 3.11+; on 3.10 these metadata checks are skipped rather than needing tomli.
tomllib = pytest.importorskip("tomllib")

ROOT = Path(__file__).resolve().parents[1]
# (project folder, distribution name)
PROJECTS = [(ROOT, "catch-env"), (ROOT / "agents", "agents")]
MIT_PHRASES = (
    "Permission is hereby granted, free of charge, to any person obtaining a copy",
    "The above copyright notice and this permission notice shall be included in all",
    'THE SOFTWARE IS PROVIDED "AS IS", WITHOUT WARRANTY OF ANY KIND',
)


def pyproject(folder: Path) -> dict[str, Any]:
    with open(folder / "pyproject.toml", "rb") as file:
        return tomllib.load(file)


def long_description(folder: Path) -> tuple[Path, str]:
    path = folder / pyproject(folder)["project"]["readme"]
    return path, path.read_text(encoding="utf-8")


def test_root_license_is_the_mit_text() -> None:
    text = (ROOT / "LICENSE").read_text(encoding="utf-8")
    assert text.startswith("MIT License\n")
    assert re.search(r"^Copyright \(c\) \d{4} \S", text, re.MULTILINE)
    for phrase in MIT_PHRASES:
        assert phrase in text


def test_agents_license_is_a_copy_of_the_root_one() -> None:
    # setuptools takes no file from outside agents/, so agents/ keeps its own copy.
    assert (ROOT / "agents" / "LICENSE").read_bytes() == (ROOT / "LICENSE").read_bytes()


@pytest.mark.parametrize(("folder", "name"), PROJECTS, ids=[name for _, name in PROJECTS])
def test_project_metadata_is_complete(folder: Path, name: str) -> None:
    config = pyproject(folder)
    project = config["project"]
    assert project["name"] == name
    # The SPDX string and license-files need setuptools 77 (PEP 639).
    assert project["license"] == "MIT"
    assert project["license-files"] == ["LICENSE"]
    assert (folder / "LICENSE").is_file()
    assert "setuptools>=77" in config["build-system"]["requires"]
    assert project["authors"] and all(author.get("name") for author in project["authors"])
    assert len(project["keywords"]) >= 3
    urls = project["urls"]
    assert urls and all(url.startswith("https://") for url in urls.values())
    classifiers = project["classifiers"]
    assert "Programming Language :: Python :: 3 :: Only" in classifiers
    assert any(c.startswith("Topic :: ") for c in classifiers)
    # PEP 639: with a license expression, License :: classifiers are an error.
    assert not [c for c in classifiers if c.startswith("License ::")]
    # The Python versions named are the ones requires-python allows.
    lowest = tuple(int(part) for part in project["requires-python"].removeprefix(">=").split("."))
    versions = [c.rsplit(" ", 1)[1] for c in classifiers if re.search(r"Python :: 3\.\d+$", c)]
    assert versions and min(tuple(int(p) for p in v.split(".")) for v in versions) == lowest


@pytest.mark.parametrize(("folder", "name"), PROJECTS, ids=[name for _, name in PROJECTS])
def test_long_description_reads_well_on_an_index_page(folder: Path, name: str) -> None:
    path, text = long_description(folder)
    assert path.suffix == ".md" and path.name != "README.md"  # README.md is the repository's
    assert text.startswith(f"# {name}\n")
    # Nothing that only works in a checkout: editable installs, repository paths, images
    # or links relative to the repository.
    for repository_only in ("-e ", "results/", "agents/", "tests/", ".png", "<img"):
        assert repository_only not in text, repository_only
    for target in re.findall(r"\]\(([^)]*)\)", text):
        assert target.startswith("https://"), f"relative link {target!r} in {path.name}"
    for block in re.findall(r"```python\n(.*?)```", text, re.DOTALL):
        compile(block, str(path), "exec")
    assert "MIT" in text


def test_catch_env_long_description_covers_install_usage_and_play() -> None:
    _, text = long_description(ROOT)
    for needed in (
        "pip install catch-env",
        '"catch-env[atari]"',
        '"catch-env[human]"',
        'gym.make("Catch-v0")',
        "gym.make_vec(",
        "catch-play",
        "catch_env.wrappers.make_env",
    ):
        assert needed in text, needed


def _setuptools_version() -> tuple[int, ...] | None:
    try:
        version = importlib.metadata.version("setuptools")
    except importlib.metadata.PackageNotFoundError:
        return None
    return tuple(int(part) for part in re.findall(r"\d+", version)[:2])


@pytest.mark.slow
def test_wheels_carry_the_license_and_index_metadata(tmp_path: Path) -> None:
    """Build both wheels (a few seconds) from a copy of the sources, so no build/ folder is
    left in the checkout, and read what an index would show."""
    source = tmp_path / "src"
    ignore = shutil.ignore_patterns("__pycache__", "*.egg-info", "build")
    shutil.copytree(ROOT / "catch_env", source / "catch_env", ignore=ignore)
    for package in ("a3c_runtime", "a3c_tools"):
        shutil.copytree(ROOT / "agents" / package, source / "agents" / package, ignore=ignore)
    for folder, _ in PROJECTS:
        target = source / folder.relative_to(ROOT)
        for name in ("pyproject.toml", "LICENSE", pyproject(folder)["project"]["readme"]):
            shutil.copy2(folder / name, target / name)
    # A recent enough setuptools here builds offline; otherwise pip fetches one, as it does
    # when it installs the project.
    installed = _setuptools_version()
    isolation = [] if installed is None or installed < (77,) else ["--no-build-isolation"]
    wheels = tmp_path / "wheels"
    command = [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", *isolation]
    subprocess.run(
        [*command, "-w", str(wheels), str(source), str(source / "agents")],
        check=True,
        timeout=300,
    )
    for folder, name in PROJECTS:
        project = pyproject(folder)["project"]
        (wheel,) = wheels.glob(f"{name.replace('-', '_')}-*.whl")
        with zipfile.ZipFile(wheel) as archive:
            dist_info = f"{name.replace('-', '_')}-{project['version']}.dist-info"
            license_text = archive.read(f"{dist_info}/licenses/LICENSE")
            metadata = archive.read(f"{dist_info}/METADATA").decode("utf-8")
        assert license_text == (ROOT / "LICENSE").read_bytes()
        if name == "agents":  # the tools' data files travel with them
            assert "a3c_tools/thesis_figures.toml" in archive.namelist()
        headers, _, body = metadata.partition("\n\n")
        assert "License-Expression: MIT" in headers.splitlines()
        assert "License-File: LICENSE" in headers.splitlines()
        assert "Description-Content-Type: text/markdown" in headers
        for classifier in project["classifiers"]:
            assert f"Classifier: {classifier}" in headers
        for label, url in project["urls"].items():
            assert f"Project-URL: {label}, {url}" in headers
        assert f"Keywords: {','.join(project['keywords'])}" in headers
        assert body.strip() == long_description(folder)[1].strip()
    # the agents' run machinery is an importable package of the agents wheel
    runtime = {p.name for p in (ROOT / "agents" / "a3c_runtime").glob("*.py")}
    (agents_wheel,) = wheels.glob("agents-*.whl")
    with zipfile.ZipFile(agents_wheel) as archive:
        packaged = {Path(n).name for n in archive.namelist() if n.startswith("a3c_runtime/")}
    assert "__init__.py" in runtime and packaged == runtime


def test_the_agents_distribution_needs_only_what_the_scripts_need() -> None:
    """matplotlib, scipy and tomli are the tools' (the `tools` extra), not the scripts'."""
    project = tomllib.loads((ROOT / "agents" / "pyproject.toml").read_text())["project"]
    names = {re.split(r"[<>=;\[ ]", d)[0] for d in project["dependencies"]}
    scripts_need = {"catch-env", "torch", "tyro", "tensorboard", "numpy", "safetensors", "pydantic"}
    assert names == scripts_need
    tools = {re.split(r"[<>=;\[ ]", d)[0] for d in project["optional-dependencies"]["tools"]}
    assert {"matplotlib", "scipy"} <= tools
    for script in (ROOT / "agents").glob("**/a3c_*.py"):
        if "a3c_tools" not in script.parts:
            assert not re.search(r"^\s*(import|from) (matplotlib|scipy)", script.read_text(), re.M)
