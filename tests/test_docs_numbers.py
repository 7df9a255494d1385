"""One number per fact: a headline figure (the README's test count and times, the default run's
time, the fast setting's time to 0.9) has one value wherever the README, a docs page or the
summary at the top of results/test_tiers/COMMAND.txt states it."""

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
TEST_TIERS = ROOT / "results" / "test_tiers" / "COMMAND.txt"

# each figure: a pattern of the phrase that states it (text with its line breaks made spaces),
# the figure its groups, and the pages that must state it (the README and the figure's home)
HEADLINES = {
    "the fast tier's test count and time": (
        r"\bfast tier\b.{0,40}?\b([\d,]+) tests in (\d+m\d\ds)\b",
        ["README.md", "results/test_tiers/COMMAND.txt"],
    ),
    "the slow tier's test count and time": (
        r"\bslow tier\b.{0,40}?\b([\d,]+) tests in (\d+m\d\ds)\b",
        ["README.md", "results/test_tiers/COMMAND.txt"],
    ),
    "the default run's time": (
        r"\bdefault run\b.{0,40}?\b1M steps in (\d+m\d\ds)\b",
        ["README.md", "docs/agents/a3c_ff.md"],
    ),
    "the fast setting's time to 0.9": (
        r"\bfast setting\b.{0,80}?\b0\.9 in (\d+-\d+ s)\b",
        ["README.md", "docs/agents/a3c_ff.md"],
    ),
}


def pages() -> dict[str, str]:
    """The README, every docs page and the test tiers' current figures (the paragraph at the top
    of their COMMAND.txt; the entries below it are the history), whitespace made single spaces."""
    paths = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    texts = {path.relative_to(ROOT).as_posix(): path.read_text() for path in paths}
    current = re.search(r"^Current .*?(?=\n\n)", TEST_TIERS.read_text(), re.M | re.S)
    assert current, f"{TEST_TIERS.relative_to(ROOT)} must open with a 'Current ...' paragraph"
    texts[TEST_TIERS.relative_to(ROOT).as_posix()] = current.group(0)
    return {name: " ".join(text.split()) for name, text in texts.items()}


def statements(pattern: str, texts: dict[str, str]) -> dict[str, set[tuple[str, ...]]]:
    """Each page's values of one figure (the pattern's groups), for the pages that state it."""
    found = {}
    for name, text in texts.items():
        values = {match.groups() for match in re.finditer(pattern, text)}
        if values:
            found[name] = values
    return found


def disagreements(found: dict[str, set[tuple[str, ...]]]) -> list[str]:
    """'page: value' for every statement, when the pages state more than one value."""
    values = set().union(*found.values()) if found else set()
    if len(values) <= 1:
        return []
    return sorted(f"{name}: {' '.join(value)}" for name, vs in found.items() for value in vs)


@pytest.mark.parametrize("headline", HEADLINES)
def test_each_headline_figure_has_one_value_across_the_docs(headline):
    pattern, homes = HEADLINES[headline]
    found = statements(pattern, pages())
    missing = [home for home in homes if home not in found]
    assert not missing, f"{headline}: not stated where it must be: {missing}"
    different = disagreements(found)
    assert not different, f"{headline}: the pages state different values: {different}"


def test_a_page_stating_another_value_is_found():
    """The check itself: a second page with another count, or the same page twice, is caught."""
    pattern = HEADLINES["the fast tier's test count and time"][0]
    same = {
        "README.md": "the fast tier runs 1228 tests in 1m08s",
        "b.md": "fast tier: 1228 tests in 1m08s",
    }
    assert statements(pattern, same).keys() == {"README.md", "b.md"}
    assert disagreements(statements(pattern, same)) == []
    other = {**same, "c.md": "the fast tier (1229 tests in 1m08s)"}
    assert disagreements(statements(pattern, other)) == [
        "README.md: 1228 1m08s", "b.md: 1228 1m08s", "c.md: 1229 1m08s"
    ]  # fmt: skip
    twice = {
        "README.md": "the fast setting reaches 0.9 in 37-73 s; the fast setting: 0.9 in 40-73 s"
    }
    pattern = HEADLINES["the fast setting's time to 0.9"][0]
    assert len(disagreements(statements(pattern, twice))) == 2


# The README's results table, Atari columns: (script, form's first word) -> (figure, line), each
# cell the mean over the committed seeds' final evaluations at 2M steps, as the table rounds it
ATARI_CELLS = {
    ("a3c_ff.py", "default"): ("fig6.9", "ff"),
    ("a3c_lws.py", "default"): ("fig6.9", "lws"),
    ("a3c_ss.py", "default"): ("fig6.9", "ss"),  # no Atari runs: "-"
    ("a3c_ww.py", "default"): ("fig6.9", "ww"),
    ("a3c_lstm.py", "default"): ("fig6.9", "lstm"),  # no Atari runs: "-"
    ("a3c_lpq.py", "default"): ("fig7.8", "lpq"),
    ("a3c_lpq.py", "as run, Figure 7.8 (a)"): ("fig7.8", "lpq_fig78"),
    ("a3c_glpq.py", "default (eq. 7.7 as written)"): ("fig7.8", "glpq"),
    ("a3c_glpq.py", "as run: the code's relative distance (b)"): ("fig7.8", "glpq_fig78"),
    ("a3c_glpq.py", "as run, Figure 7.8 (c)"): ("fig7.8", "glpq_as_run"),
}


def atari_means() -> dict[tuple[str, str, str], float]:
    """(figure, game, line) -> the mean final score over its committed seeds."""
    import csv

    scores: dict[tuple[str, str, str], list[float]] = {}
    for figure in ("fig6.9", "fig7.8"):
        with open(ROOT / "results" / "atari_figures" / figure / "results.csv") as f:
            for row in csv.DictReader(f):
                key = (figure, row["game"], row["line"])
                scores.setdefault(key, []).append(float(row["final_score"]))
    return {key: sum(v) / len(v) for key, v in scores.items()}


def test_the_readmes_atari_columns_are_the_committed_runs_means():
    means = atari_means()
    table = {}
    for line in (ROOT / "README.md").read_text().splitlines():
        cells = [c.strip() for c in line.strip("|").split("|")]
        if len(cells) == 7 and cells[0].startswith("`a3c_"):
            table[(cells[0].strip("`"), cells[1])] = (cells[4], cells[5])
    assert set(table) == set(ATARI_CELLS), "README.md's results table: rows changed"
    for (script, form), (figure, line) in ATARI_CELLS.items():
        for game, cell in zip(("Breakout", "BeamRider"), table[(script, form)], strict=True):
            key = (figure, game, line)
            if key not in means:
                assert cell == "-", f"README.md: {script} {form} {game}: no committed runs"
                continue
            digits = 1 if game == "Breakout" else 0  # the table's rounding
            assert cell == f"{means[key]:.{digits}f}", (script, form, game, cell, means[key])
