"""The thesis's claims, each with our evidence, a 95% interval and a verdict: docs/claims.md.

    python -m a3c_tools.thesis_claims                  # print the page
    python -m a3c_tools.thesis_claims -o docs/claims.md
    python -m a3c_tools.thesis_claims --check docs/claims.md   # exit 1 if the page is stale

The claims are in agents/a3c_tools/thesis_claims.toml. A claim compares two lines of the same sweep
design (the same learning rates and run seeds, so runs pair up by run_id): each line's
results.csv, committed under results/, gives one score per run (the mean of its final 5
evaluations). The pairing, the effect with its 95% BCa interval and the verdict are
a3c_tools.paired's (its docstring gives the rules), which `a3c_tools.compare` uses too. A claim
whose lines have not been run yet, or that has one run per line (the Atari figures), gets no
interval: the row says what would decide it.
"""

from __future__ import annotations

import argparse
import sys
from collections import Counter
from pathlib import Path

from a3c_tools import run_main
from a3c_tools.paired import pair, read_scores

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[2]  # the repository
CLAIMS = Path(__file__).with_name("thesis_claims.toml")


def scores(folder: str, column: str = "score") -> dict[str, float]:
    """run_id -> score of the finished runs in the committed folder's results.csv."""
    return read_scores(ROOT / folder / "results.csv", column)


def evidence(claim: dict) -> tuple[str, str, str]:
    """(our numbers, the effect with its interval, the verdict) of one claim."""
    if "baseline" not in claim:
        return claim["ours"], "-", claim["verdict"]
    column = claim.get("score", "score")
    paired = pair(scores(claim["baseline"], column), scores(claim["line"], column))
    if paired is None:  # the command goes to the page's list of what is missing
        return "not run yet (the command is in the last section)", "-", "not run yet"
    names = claim.get("names", ["baseline", "line"])
    ours = (
        f"{names[1]} {paired.other.mean():.3f} vs {names[0]} {paired.base.mean():.3f}"
        + (" (the mean over all evaluations)" if column == "score_all" else "")
        + f" (n = {paired.runs} paired "
        f"runs; [{claim['line']}]({link(claim['line'])}), [{claim['baseline']}]"
        f"({link(claim['baseline'])}))"
    )
    return ours, paired.shown(), paired.verdict(claim["expect"])


def link(folder: str) -> str:
    """A docs-relative link to a results folder's results.csv."""
    return f"../{folder}/results.csv"


VERDICTS = ("reproduced", "contradicted", "inconclusive", "not run yet")  # the tally's order


def tally(verdicts: list[str]) -> str:
    """How many rows have each verdict: "**At a glance**: 3 rows: 2 reproduced, 1 ..."."""
    counts = Counter(call.partition(":")[0] for call in verdicts)
    heads = [*VERDICTS, *sorted(set(counts) - set(VERDICTS))]
    parts = ", ".join(f"{counts[head]} {head}" for head in heads if counts[head])
    return f"**At a glance**: {len(verdicts)} rows: {parts}."


def render(claims: dict) -> str:
    """The whole page, in Markdown."""
    rows = [evidence(claim) for section in claims["section"] for claim in section["claim"]]
    out, missing = [claims["intro"].strip(), "", tally([call for *_, call in rows]), ""], {}
    next_row = iter(rows)
    for section in claims["section"]:
        out += [f"## {section['title']}", ""]
        if "text" in section:
            out += [section["text"].strip(), ""]
        out += [
            "| claim | where | form | thesis's evidence | ours | effect [95% CI] | verdict |",
            "|---|---|---|---|---|---|---|",
        ]
        for claim in section["claim"]:
            ours, effect, call = next(next_row)
            if call == "not run yet" and "command" in claim:
                missing.setdefault(claim["command"], []).append(claim["where"])
            head, _, rest = call.partition(":")
            verdict_cell = f"**{head}**" + (f": {rest.strip()}" if rest else "")
            cells = [claim["claim"], claim["where"], claim.get("form", "-"), claim["thesis"],
                     ours, effect, verdict_cell]  # fmt: skip
            out.append("| " + " | ".join(" ".join(cell.split()) for cell in cells) + " |")
        out.append("")
    out.append(claims["outro"].strip())
    if missing:  # the sentence that introduces the list only with a list to introduce
        out += ["", claims.get("missing", "The rows *not run yet*, and their commands:").strip()]
        out += [""] + [f"- {', '.join(dict.fromkeys(wheres))}: `{command}`"
                       for command, wheres in missing.items()]  # fmt: skip
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m a3c_tools.thesis_claims", description=__doc__.split("\n")[0]
    )
    parser.add_argument("-o", "--out", type=Path, help="write the page here (default: stdout)")
    parser.add_argument("--check", type=Path, help="exit 1 if this page differs from the data")
    opts = parser.parse_args(argv)
    with open(CLAIMS, "rb") as f:
        page = render(tomllib.load(f))
    if opts.check is not None:
        if not opts.check.is_file() or opts.check.read_text() != page:
            print(f"{opts.check} is stale: python -m a3c_tools.thesis_claims -o {opts.check}")
            return 1
        print(f"{opts.check} holds what the committed results give")
    elif opts.out is not None:
        opts.out.write_text(page)
        print(f"wrote {opts.out}")
    else:
        sys.stdout.write(page)
    return 0


if __name__ == "__main__":
    run_main(main)
