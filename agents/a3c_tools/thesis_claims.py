"""The thesis's claims, each with our evidence, a 95% interval and a verdict: docs/claims.md.

    python -m a3c_tools.thesis_claims                  # print the page
    python -m a3c_tools.thesis_claims -o docs/claims.md
    python -m a3c_tools.thesis_claims --check docs/claims.md   # exit 1 if the page is stale

The claims are in agents/a3c_tools/thesis_claims.toml. A claim compares two lines of the same sweep
design (the same learning rates and run seeds, so runs pair up by run_id): each line's
results.csv, committed under results/, gives one score per run (the mean of its final 5
evaluations). The effect is the mean over paired runs of (line - baseline), with a 95% BCa
interval from `scipy.stats.bootstrap` (paired resampling of runs, 10,000 resamples, seed 0).

Verdicts, from the interval and the claim's direction:
- "better" / "worse": reproduced when the interval lies wholly on the claimed side of 0,
  contradicted when it lies wholly on the other side, inconclusive otherwise;
- "comparable": reproduced when the interval lies within +-MARGIN, contradicted when it lies
  wholly outside it, inconclusive otherwise.
An inconclusive row states the runs per line that would decide it if the effect and the spread
stayed as measured (the interval narrows as 1 / sqrt(runs)). A claim whose lines have not been
run yet, or that has one run per line (the Atari figures), gets no interval: the row says what
would decide it.
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
from collections import Counter
from pathlib import Path

import numpy as np
from scipy.stats import bootstrap

from a3c_tools import run_main

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[2]  # the repository
CLAIMS = Path(__file__).with_name("thesis_claims.toml")
MARGIN = 0.05  # a Catch score difference (success rate) below which two lines are "comparable"
MAX_RUNS = 400  # beyond this many runs per line, more runs of 250k steps would not decide it


def scores(folder: str, column: str = "score") -> dict[str, float]:
    """run_id -> score of the finished runs in folder/results.csv ({} if there is none): the
    mean of the final 5 evaluations, or with column "score_all" the mean of all of them."""
    path = ROOT / folder / "results.csv"
    if not path.is_file():
        return {}
    with open(path, newline="") as f:
        return {
            row["run_id"]: float(row[column]) for row in csv.DictReader(f) if row["status"] == "ok"
        }


def interval(differences: np.ndarray) -> tuple[float, float]:
    """95% BCa interval of the mean of paired differences, over runs."""
    if np.ptp(differences) == 0:
        return float(differences[0]), float(differences[0])
    result = bootstrap(
        (differences,), np.mean, confidence_level=0.95, n_resamples=10_000, method="BCa",
        random_state=np.random.default_rng(0),
    )  # fmt: skip
    return float(result.confidence_interval.low), float(result.confidence_interval.high)


def verdict(expect: str, effect: float, low: float, high: float, runs: int) -> str:
    """The verdict of an interval, and for an inconclusive one the runs that would decide it."""
    if expect in ("better", "worse"):
        sign = 1 if expect == "better" else -1
        side_low, side_high = sorted((sign * low, sign * high))
        if side_low > 0:
            return "reproduced"
        if side_high < 0:
            return "contradicted"
        distance = abs(effect)  # how far the interval's centre is from 0
    else:
        if low >= -MARGIN and high <= MARGIN:
            return "reproduced"
        if low > MARGIN or high < -MARGIN:
            return "contradicted"
        distance = abs(abs(effect) - MARGIN)  # how far the centre is from the margin
    half_width = (high - low) / 2
    if distance == 0 or runs * (half_width / distance) ** 2 > MAX_RUNS:
        return f"inconclusive: more runs at this budget would not decide it (> {MAX_RUNS} per line)"
    needed = math.ceil(runs * (half_width / distance) ** 2)
    return f"inconclusive: about {max(needed, runs + 1)} runs per line would decide it"


def evidence(claim: dict) -> tuple[str, str, str]:
    """(our numbers, the effect with its interval, the verdict) of one claim."""
    if "baseline" not in claim:
        return claim["ours"], "-", claim["verdict"]
    column = claim.get("score", "score")
    base, line = scores(claim["baseline"], column), scores(claim["line"], column)
    paired = sorted(set(base) & set(line))
    if len(paired) < 2:  # the command goes to the page's list of what is missing
        return "not run yet (the command is in the last section)", "-", "not run yet"
    b = np.array([base[r] for r in paired])
    x = np.array([line[r] for r in paired])
    low, high = interval(x - b)
    effect = float(np.mean(x - b))
    names = claim.get("names", ["baseline", "line"])
    ours = (
        f"{names[1]} {x.mean():.3f} vs {names[0]} {b.mean():.3f}"
        + (" (the mean over all evaluations)" if column == "score_all" else "")
        + f" (n = {len(paired)} paired "
        f"runs; [{claim['line']}]({link(claim['line'])}), [{claim['baseline']}]"
        f"({link(claim['baseline'])}))"
    )
    shown = f"{effect:+.3f} [{low:+.3f}, {high:+.3f}]"
    return ours, shown, verdict(claim["expect"], effect, low, high, len(paired))


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
