"""Tests of a3c_tools.thesis_claims (docs/claims.md from the committed results): the page and its
forest plot hold what the script makes of the data, the plot draws the page's rows, and the
handling of lines not run yet. The verdict rule and the paired bootstrap, a3c_tools.paired's,
are tested in test_compare.py."""

import csv
import dataclasses
import re

from a3c_tools import thesis_claims as claims  # noqa: E402
from conftest import ROOT, run_main


def test_the_claims_page_holds_what_the_committed_results_give():
    with open(claims.CLAIMS, "rb") as f:
        page = claims.render(claims.tomllib.load(f))
    assert (ROOT / "docs" / "claims.md").read_text() == page, (
        "docs/claims.md is stale: python -m a3c_tools.thesis_claims -o docs/claims.md"
    )


def test_the_check_option_fails_on_a_stale_page(tmp_path):
    stale = tmp_path / "claims.md"
    stale.write_text("# an old page\n")
    done = run_main(claims.main, ["--check", str(stale)])
    assert done.returncode == 1 and "are stale" in done.stdout  # the page, and no figure
    assert done.stdout.strip().endswith(f"python -m a3c_tools.thesis_claims -o {stale}")


def test_the_committed_page_and_figure_pass_the_check():
    done = run_main(claims.main, ["--check", "docs/claims.md"])
    assert done.returncode == 0, done.stdout  # the stdout names the command that regenerates


def test_the_check_fails_on_a_missing_or_changed_figure(tmp_path, monkeypatch):
    page = tmp_path / "claims.md"
    assert run_main(claims.main, ["-o", str(page)]).returncode == 0
    figure = tmp_path / "img" / "claims_forest.png"
    assert figure.is_file()
    assert run_main(claims.main, ["--check", str(page)]).returncode == 0
    # a line's scores changed: one row's numbers change, on the page and in the figure
    scores = claims.scores

    def shifted(folder: str, column: str = "score") -> dict[str, float]:
        bump = 0.01 if folder.endswith("glpq_growth") else 0.0
        return {run: score + bump for run, score in scores(folder, column).items()}

    monkeypatch.setattr(claims, "scores", shifted)
    done = run_main(claims.main, ["--check", str(page)])
    assert done.returncode == 1 and done.stdout.startswith(f"{page} and {figure} are stale: ")
    monkeypatch.undo()
    # one row's effect moved: the page still holds, the figure does not
    points = claims.plotted(figure)
    points[0] = dataclasses.replace(points[0], effect=points[0].effect + 0.001)
    claims.draw(points, figure)
    done = run_main(claims.main, ["--check", str(page)])
    assert done.returncode == 1 and done.stdout.startswith(f"{figure} is stale: ")
    figure.write_bytes(b"not a PNG")
    assert run_main(claims.main, ["--check", str(page)]).returncode == 1
    figure.unlink()
    done = run_main(claims.main, ["--check", str(page)])
    assert done.returncode == 1 and done.stdout.startswith(f"{figure} is stale: ")


def test_the_forest_plot_draws_the_pages_rows_with_their_verdicts_colours():
    text = (ROOT / "docs" / "claims.md").read_text()
    assert f"]({claims.FIGURE.as_posix()})" in text.split("## ")[0]  # it opens the page
    rows, section = [], None  # (section, effect cell, verdict) of each row with an interval
    for line in text.splitlines():
        if line.startswith("## "):
            section = line[3:]
        cells = line.split(" | ")
        if line.startswith("| ") and re.fullmatch(r"[+-]\d\.\d{3} \[.*\]", cells[-2]):
            rows.append((section, cells[-2], cells[-1].split("**")[1]))
    points = claims.plotted(ROOT / "docs" / claims.FIGURE)
    drawn = [(p.section, f"{p.effect:+.3f} [{p.low:+.3f}, {p.high:+.3f}]", p.verdict)
             for p in points]  # fmt: skip
    assert drawn == rows and len(rows) >= 25
    assert all(point.colour == claims.COLOURS[point.verdict] for point in points)
    assert set(claims.COLOURS) == {"reproduced", "contradicted", "inconclusive"}
    assert len(set(claims.COLOURS.values())) == 3  # one colour to each verdict
    # the caption counts the table rows left off: every row, less the heads, less those drawn
    left_off = text.count("\n| ") - text.count("\n|---") - len(rows)
    assert f"*The {len(rows)} rows with an interval" in text
    assert f"Left off, having no interval: {left_off} " in text


def test_every_claim_names_its_place_form_and_evidence_and_its_lines_exist_or_a_command():
    with open(claims.CLAIMS, "rb") as f:
        data = claims.tomllib.load(f)
    rows = [claim for section in data["section"] for claim in section["claim"]]
    assert len(rows) >= 25
    for claim in rows:
        assert claim["claim"] and claim["where"] and claim["form"] and claim["thesis"]
        if "baseline" in claim:
            assert claim["expect"] in ("better", "worse", "comparable")
            assert claim["command"] and len(claim["names"]) == 2
        else:
            assert claim["ours"] and claim["verdict"]
    wheres = " ".join(claim["where"] for claim in rows)
    for figure in ("6.3", "6.5", "6.6", "6.7", "6.8", "7.1", "7.2", "7.3", "7.5", "7.6", "7.7",
                   "6.9", "6.10", "7.8", "A.1", "A.2", "A.3", "C.1", "Chapter 8"):  # fmt: skip
        assert figure in wheres, figure


def test_lines_pair_by_run_id_and_missing_lines_say_not_run_yet(tmp_path, monkeypatch):
    monkeypatch.setattr(claims, "ROOT", tmp_path)
    for folder, values in (("a", [0.5, 0.6, 0.7]), ("b", [0.7, 0.8, 0.9, 0.1])):
        (tmp_path / folder).mkdir()
        with open(tmp_path / folder / "results.csv", "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["run_id", "status", "score", "score_all"])
            for i, value in enumerate(values):
                writer.writerow([f"run-{i:04d}", "ok", value, value / 2])
    claim = {"baseline": "a", "line": "b", "names": ["A", "B"], "expect": "better",
             "command": "make b"}  # fmt: skip
    ours, effect, verdict = claims.evidence(claim)
    assert "n = 3 paired runs" in ours and effect.startswith("+0.200")  # run-0003 has no pair
    assert verdict == "reproduced"  # the same +0.2 in every pair
    # "score": "score_all" compares the mean over all evaluations (here half the final score)
    ours, effect, verdict = claims.evidence({**claim, "score": "score_all"})
    assert "mean over all evaluations" in ours and effect.startswith("+0.100")
    ours, effect, verdict = claims.evidence({**claim, "line": "missing"})
    assert verdict == "not run yet" and ours.startswith("not run yet") and effect == "-"
    data = {"intro": "# Claims", "outro": "## Missing", "section": [
        {"title": "S", "claim": [{**claim, "line": "missing", "claim": "c", "where": "Fig 1",
                                  "form": "as run", "thesis": "t"}]}]}  # fmt: skip
    page = claims.render({**data, "missing": "Not run yet:"})
    assert page.endswith("## Missing\n\nNot run yet:\n\n- Fig 1: `make b`\n")  # the command
    # every line run: no sentence announcing a list of what is missing, no dangling colon
    data["section"][0]["claim"][0]["line"] = claim["line"]
    page = claims.render({**data, "missing": "Not run yet:"})
    assert page.endswith("## Missing\n") and "Not run yet:" not in page


def test_the_page_opens_with_a_tally_of_its_verdicts():
    calls = ["inconclusive: about 9 runs", "reproduced", "no claim to test", "reproduced"]
    assert claims.tally(calls) == (
        "**At a glance**: 4 rows: 2 reproduced, 1 inconclusive, 1 no claim to test."
    )
    page = (ROOT / "docs" / "claims.md").read_text()
    cells = [row.split(" | ")[-1] for row in page.splitlines() if row.startswith("| ")]
    heads = [cell.strip("| ").split("**")[1] for cell in cells if cell.startswith("**")]
    assert f"**At a glance**: {len(heads)} rows: " in page
    for head in set(heads):
        assert f"{heads.count(head)} {head}" in page.split("**At a glance**")[1].split("\n")[0]
