"""One number per fact: a headline figure (the README's test count and times, the default run's
time, the fast setting's time to 0.9) has one value wherever the README, a docs page or the
summary at the top of results/test_tiers/COMMAND.txt states it; the README's Atari columns and
the Atari prose (docs/atari.md's thesis figures, the agent pages' Atari sections) state only what
the committed runs of results/atari_figures give."""

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


# The Atari prose: docs/atari.md's section on the thesis's Atari figures and each agent page's
# "## Atari" section restate scores of the committed runs of results/atari_figures by hand. Every
# score they state must be one those runs give: a seed's evaluation, a line's mean at an
# evaluation step, a paired difference of two lines of a game with its 95% t interval, or the
# game's random play and its threshold (random play plus 5% of the human - random range).
AGENT_PAGES = sorted((ROOT / "docs" / "agents").glob("a3c_*.md"))
ATARI_PROSE = {
    "docs/atari.md": "## The thesis's Atari figures as one command each",
    **{f"docs/agents/{page.name}": "## Atari" for page in AGENT_PAGES},
}
# what is not a score: code spans, link targets, and figure, section and equation numbers
NOT_SCORES = re.compile(
    r"`[^`]*`|\]\([^)]*\)|\b(?:Figures?|[Ss]ections?|eq\.) \d+\.\d+(?:(?:, | and )\d+\.\d+)*"
)
# a number with a decimal point, not a step count (1.5M), ratio (1.6x) or percentage
STATED = re.compile(r"(?<![\w.,])([+-]?\d{1,3}(?:,\d{3})*\.\d+)(?![\d.]|M\b|x\b|%)")
# settings, not scores: Figure 6.10's lines are named by their lambda_V (1.0, 0.5; Algorithm 1's
# 0.5 and 0.25), and RMSprop's eps (0.1); a score stated as one of these is not checked
SETTINGS = {"1.0", "0.5", "0.25", "0.1"}


def atari_prose_sections() -> dict[str, str]:
    """Each page's Atari section (from its heading to the next of its level), one line."""
    sections = {}
    for name, heading in ATARI_PROSE.items():
        text = (ROOT / name).read_text()
        start = text.index(heading) if heading in text else None
        if start is None:
            continue
        end = text.find("\n## ", start + len(heading))
        section = NOT_SCORES.sub(" ", text[start : end if end > 0 else None])
        sections[name] = " ".join(section.split())
    return sections


def derivable_atari_scores() -> tuple[list[float], list[tuple[float, float, float]]]:
    """Every score the committed Atari figure runs give (see above), unrounded, and every paired
    comparison's (mean difference, low, high)."""
    import csv

    import numpy as np
    from a3c_tools.paired import interval, random_play

    values: list[float] = []
    triples: list[tuple[float, float, float]] = []
    finals: dict[tuple[str, str], dict[int, float]] = {}  # (game, figure/line) -> seed -> final
    for evaluations in sorted((ROOT / "results/atari_figures").glob("*/*/*/evaluations.csv")):
        figure, game, line = evaluations.parent.relative_to(ROOT / "results/atari_figures").parts
        by_step: dict[int, list[float]] = {}
        last: dict[int, tuple[int, float]] = {}  # seed -> its final evaluation (step, score)
        with open(evaluations) as f:
            for row in csv.DictReader(f):
                step, score = int(row["global_step"]), float(row["mean_return"])
                by_step.setdefault(step, []).append(score)
                last[int(row["seed"])] = max(last.get(int(row["seed"]), (-1, 0.0)), (step, score))
                values.append(score)
        values += [sum(v) / len(v) for v in by_step.values()]
        finals[(game, f"{figure}/{line}")] = {seed: score for seed, (_, score) in last.items()}
    for (game, a), a_finals in finals.items():
        for (other_game, b), b_finals in finals.items():
            seeds = sorted(a_finals.keys() & b_finals.keys())
            if other_game != game or a == b or len(seeds) < 2:
                continue
            differences = np.array([a_finals[s] - b_finals[s] for s in seeds])
            triples.append((float(differences.mean()), *interval(differences)))
            values += triples[-1]
    for game in {game for game, _ in finals}:
        random, slack = random_play(f"{game}NoFrameskip-v4")
        values += [random, random + slack]
    return values, triples


# a paired comparison as the prose states it: "+7.0 [-17.2, +31.1]"
INTERVAL = re.compile(r"([+-]\d[\d,]*\.\d+) \[([+-]\d[\d,]*\.\d+), ([+-]\d[\d,]*\.\d+)\]")


def rounds_to(value: float, stated: str) -> bool:
    """Whether value, rounded to the decimals stated has, is the stated number."""
    decimals = len(stated.split(".")[1])
    return abs(round(value, decimals) - float(stated.replace(",", ""))) < 10**-decimals / 2


def underivable(text: str, derivable: tuple[list, list]) -> list[str]:
    """The scores stated in text that no value gives at the decimals they are stated to, and the
    intervals stated that are not one comparison's (its mean, low and high together)."""
    values, triples = derivable
    wrong = [
        stated
        for stated in STATED.findall(text)
        if stated not in SETTINGS and not any(rounds_to(v, stated) for v in values)
    ]
    for match in INTERVAL.finditer(text):
        if not any(all(map(rounds_to, t, match.groups())) for t in triples):
            wrong.append(match.group(0))
    return wrong


def test_the_atari_prose_states_only_scores_the_committed_runs_give():
    sections = atari_prose_sections()
    assert set(sections) >= {"docs/atari.md", "docs/agents/a3c_glpq.md"}, "a section moved"
    values = derivable_atari_scores()
    stated = sum(len(STATED.findall(text)) for text in sections.values())
    assert stated > 100, f"only {stated} scores found: the pattern no longer reads the prose"
    wrong = {name: w for name, text in sections.items() if (w := underivable(text, values))}
    assert not wrong, f"scores no committed Atari run gives (stale or mistyped): {wrong}"


def test_a_mistyped_atari_score_is_found():
    derivable = derivable_atari_scores()
    glpq = atari_prose_sections()["docs/agents/a3c_glpq.md"]
    assert underivable(glpq, derivable) == []
    assert "71.9" in glpq
    assert underivable(glpq.replace("71.9", "71.8", 1), derivable) == ["71.8"]
    atari = atari_prose_sections()["docs/atari.md"]
    assert "-20.0 [-22.4, -17.7]" in atari  # Breakout, LWS - FF: each number alone is derivable
    assert underivable(atari.replace("-20.0 [-22.4", "-20.1 [-22.4", 1), derivable) == [
        "-20.1 [-22.4, -17.7]"
    ]
    not_scores = "Figures 6.9 and 7.8 at 1.5M steps, 1.6x faster, 5.5% of it, `--vf-coef 2.5`"
    assert underivable(NOT_SCORES.sub(" ", not_scores), derivable) == []


def test_the_watch_section_states_the_committed_evaluate_output():
    """docs/atari.md's `--evaluate` of the committed Breakout checkpoint: the mean, the range and
    the std it states are those of the command's committed output (results/breakout_a3c_ff/
    evaluate.txt), and the scores there are the mean's."""
    out = (ROOT / "results" / "breakout_a3c_ff" / "evaluate.txt").read_text()
    scores = [float(s) for s in re.findall(r"^episode \d+: score (\S+)$", out, re.M)]
    found = re.search(r"mean score ([\d.]+) \+- ([\d.]+) over (\d+) episodes$", out, re.M)
    mean, std, n = found.groups()
    assert len(scores) == int(n) == 10 and abs(sum(scores) / len(scores) - float(mean)) < 1e-3
    text = (ROOT / "docs" / "atari.md").read_text()
    section = " ".join(text[text.index("## Watch a trained agent") :].split())
    spread = f"{min(scores):g} to {max(scores):g}, std {float(std):.1f}"
    stated = f"the mean: {float(mean):.1f} ({spread})"
    assert stated in section, f"docs/atari.md does not state {stated!r}"
