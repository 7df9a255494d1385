"""Mutation sample: what share of mutants that nobody chose does the fast tier catch?

cosmic-ray (a mutation tool for Python) lists every mutant its operators make of the targets;
this script draws a seeded random sample of them, applies each in turn to a scratch copy of the
tree and runs the fast tier there (`pytest -x -m "not slow"`, the test files of the mutated
module first, then the others, and the lint and drift tests last, so that "caught by" names a
behaviour test wherever one catches it). A timeout is never counted as caught. Two samples:

- `--targets algorithm` (the default; seed 53, results/mutation_sample): the algorithm code,
  catch_env/, the seven thesis scripts' network, returns, loss and worker, and a3c_runtime's
  optimizer, clipping, learning-rate schedule, evaluation and seeding;
- `--targets runtime` (seed 69, results/mutation_sample_runtime): the run machinery, every line
  of agents/a3c_runtime/ (workers and Hogwild, seeding, evaluation, checkpoints, resume, the
  run folder and log, snapshots, supervision, the flags, train() in a3c.py, replay).

    python tests/mutation_sample.py                        # the first: draw, run, report
    python tests/mutation_sample.py --targets runtime      # the second

The draw (seed, size, the mutants with their lines) goes to OUT/sample.tsv and each mutant's
result to OUT/results.tsv as it finishes; run again, the script skips the mutants already in
results.tsv (resumable). OUT/summary.txt counts them. The draw depends only on the target files
(the same files, the same draw); a sample.tsv that holds another draw (the files changed since)
is refused: remove it to draw again. `--draw-only` writes sample.tsv and stops; `--only ID ...`
runs only those mutants (to time a few). Equivalent mutants (no behaviour can tell them apart)
are classified by hand, in OUT/COMMAND.txt. Not collected by pytest.
"""

from __future__ import annotations

import argparse
import ast
import csv
import dataclasses
import random
import shutil
import sys
import tempfile
import time
from pathlib import Path

from cosmic_ray import plugins
from cosmic_ray.commands.init import init as cosmic_ray_init
from cosmic_ray.mutating import use_mutation
from cosmic_ray.work_db import use_db
from mutation_check import ROOT, imports_from, make_scratch, run_pytest

SCRIPTS = [f"agents/a3c_{n}.py" for n in ("ff", "lws", "ss", "ww", "lstm", "lpq", "glpq")]
# the scripts' flags, env and entry point are not the algorithm
NOT_ALGORITHM = {"Args", "make_env", "make_vector_env", "main"}
RUNTIME = {
    "agents/a3c_runtime/hogwild.py": {
        "annealed_lr", "clip_gradients", "clip_stacked", "RMSprop", "SharedAdam", "make_optimizer",
        "process_seed", "seed_everything",
    },
    "agents/a3c_runtime/evaluation.py": {
        "play_episodes", "make_eval_envs", "evaluate_network", "evaluator",
        "evaluation_episodes", "evaluate",
    },
}  # fmt: skip
CATCH_ENV = sorted(p.relative_to(ROOT).as_posix() for p in (ROOT / "catch_env").glob("*.py"))
# the test files to run first for a mutated file (then every other, the lint and drift last)
FIRST = {
    "catch_env/catch.py": ["tests/test_catch.py"],
    "catch_env/wrappers.py": ["tests/test_wrappers.py"],
    "catch_env/play.py": ["tests/test_play.py"],
    "catch_env/rendering.py": ["tests/test_catch.py", "tests/test_play.py"],
    "agents/a3c_runtime/hogwild.py": ["tests/test_runtime_hogwild.py", "tests/test_workers.py"],
    "agents/a3c_runtime/evaluation.py": ["tests/test_runtime_evaluation.py"],
    **{
        s: ["tests/test_a3c_units.py", "tests/test_batched_actors.py", "tests/test_workers.py",
            "tests/test_variants_arch.py", "tests/test_prototype_policies.py"]
        for s in SCRIPTS
    },
}  # fmt: skip
LAST = ["tests/test_repo.py", "tests/test_script_drift.py"]  # ruff and the scripts' drift

# the second sample: the run machinery, every line of agents/a3c_runtime/
MACHINERY = sorted(
    p.relative_to(ROOT).as_posix() for p in (ROOT / "agents" / "a3c_runtime").glob("*.py")
)
FIRST_MACHINERY = {
    f"agents/a3c_runtime/{module}.py": [f"tests/{t}.py" for t in tests]
    for module, tests in {
        "__init__": ["test_runtime_train", "test_workers"],
        "a3c": ["test_runtime_train", "test_workers", "test_runtime_supervision"],
        "checkpoints": ["test_runtime_checkpoints", "test_safe_loading", "test_runtime_resume"],
        "evaluation": ["test_runtime_evaluation", "test_runtime_train"],
        "flags": ["test_runtime_flags", "test_runtime_train"],
        "hogwild": ["test_runtime_hogwild", "test_workers", "test_runtime_train"],
        "replay": ["test_runtime_replay", "test_batched_actors"],
        "resume": ["test_runtime_resume", "test_runtime_train"],
        "run_folder": ["test_runtime_run_folder", "test_runtime_train"],
        "run_log": ["test_runtime_run_log", "test_runtime_train"],
        "snapshots": ["test_runtime_snapshots", "test_runtime_train"],
        "supervision": ["test_runtime_supervision", "test_runtime_train"],
    }.items()
}  # fmt: skip


@dataclasses.dataclass(frozen=True)
class Targets:
    files: list[str]
    first: dict[str, list[str]]  # the test files to run first for a mutated file
    seed: int
    out: str
    whole_files: bool  # every line of every file, or target_lines' choice


TARGETS = {
    "algorithm": Targets([*CATCH_ENV, *SCRIPTS, *RUNTIME], FIRST, 53,
                         "results/mutation_sample", whole_files=False),
    "runtime": Targets(MACHINERY, FIRST_MACHINERY, 69,
                       "results/mutation_sample_runtime", whole_files=True),
}  # fmt: skip


def target_lines(path: str) -> set[int]:
    """The lines of a file whose mutants are drawn from: all of catch_env; in a script every
    top-level function and class but NOT_ALGORITHM's; in a3c_runtime the named ones."""
    text = (ROOT / path).read_text()
    if path.startswith("catch_env/"):
        return set(range(1, len(text.splitlines()) + 1))
    tree = ast.parse(text)
    wanted = RUNTIME.get(path)
    lines = set()
    for node in tree.body:
        if not isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            continue
        if (wanted is None and node.name not in NOT_ALGORITHM) or (wanted and node.name in wanted):
            lines.update(range(node.lineno, node.end_lineno + 1))
    return lines


def annotation_spans(path: Path) -> list[tuple[tuple[int, int], tuple[int, int]]]:
    """The (start, end) positions of a file's function annotations where the file has `from
    __future__ import annotations`: there no code evaluates them, so a mutant in one (`int |
    None` -> `int & None`) is equivalent by construction and is not drawn. (Elsewhere Python
    evaluates them when it defines the function, and such a mutant is drawn.)"""
    spans = []
    text = path.read_text()
    if "from __future__ import annotations" not in text:
        return spans
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            a = node.args
            args = [*a.posonlyargs, *a.args, *a.kwonlyargs, a.vararg, a.kwarg]
            notes = [x.annotation for x in args if x is not None and x.annotation is not None]
            for note in [*notes, node.returns]:
                if note is not None:
                    spans.append(((note.lineno, note.col_offset),
                                  (note.end_lineno, note.end_col_offset)))  # fmt: skip
    return spans


def all_mutants(scratch: Path, targets: Targets) -> list[dict]:
    """Every mutant cosmic-ray's operators make of the targets' lines, in a stable order."""
    files = targets.files
    with tempfile.TemporaryDirectory() as folder, use_db(Path(folder) / "session.sqlite") as db:
        cosmic_ray_init([scratch / f for f in files], db, {})
        specs = [m for item in db.work_items for m in item.mutations]
    mutants = []
    if targets.whole_files:
        lines = {f: set(range(1, len((ROOT / f).read_text().splitlines()) + 1)) for f in files}
    else:
        lines = {f: target_lines(f) for f in files}
    notes = {f: annotation_spans(scratch / f) for f in files}
    for spec in specs:
        path = Path(spec.module_path).relative_to(scratch).as_posix()
        start = tuple(spec.start_pos)
        in_note = any(low <= start < high for low, high in notes[path])
        if spec.start_pos[0] in lines[path] and not in_note:
            mutants.append(
                {"file": path, "line": spec.start_pos[0], "operator": spec.operator_name,
                 "occurrence": spec.occurrence, "definition": spec.definition_name or ""}
            )  # fmt: skip
    return sorted(mutants, key=lambda m: (m["file"], m["operator"], m["occurrence"]))


def changed_line(original: str, mutated: str) -> tuple[str, str]:
    """The first line that differs, before and after (for the report)."""
    for before, after in zip(original.splitlines(), mutated.splitlines(), strict=False):
        if before != after:
            return before.strip(), after.strip()
    return "", ""


def write_rows(path: Path, rows: list[dict], append: bool = False) -> None:
    new = not path.exists() or not append
    with path.open("a" if append else "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]), delimiter="\t")
        if new:
            writer.writeheader()
        writer.writerows(rows)


def read_rows(path: Path) -> list[dict]:
    if not path.exists():
        return []
    with path.open(newline="") as f:
        return list(csv.DictReader(f, delimiter="\t"))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument(
        "--targets",
        choices=sorted(TARGETS),
        default="algorithm",
        help="the algorithm code (default) or the run machinery, agents/a3c_runtime/",
    )
    parser.add_argument(
        "--out", type=Path, default=None, help="default: results/mutation_sample(_runtime)"
    )
    parser.add_argument("--size", type=int, default=110, help="mutants drawn (default 110)")
    parser.add_argument(
        "--seed", type=int, default=None, help="the draw's seed (default 53; runtime: 69)"
    )
    parser.add_argument("--draw-only", action="store_true", help="write sample.tsv and stop")
    parser.add_argument("--only", nargs="+", metavar="ID", help="run only these mutants")
    parser.add_argument(
        "--timeout",
        type=float,
        default=None,
        help="seconds per mutant (default: 3 times the unmutated fast tier's, 300 at least: a "
        "mutant that hangs a test is not caught, and costs no more than that)",
    )
    args = parser.parse_args()
    targets = TARGETS[args.targets]
    args.out = args.out or ROOT / targets.out
    args.seed = targets.seed if args.seed is None else args.seed
    args.out.mkdir(parents=True, exist_ok=True)

    scratch = make_scratch()
    try:
        shadowing = imports_from(scratch)
        if shadowing:
            print(f"the copy's tests would not import the copy's packages: {shadowing}",
                  file=sys.stderr)  # fmt: skip
            return 2
        population = all_mutants(scratch, targets)
        drawn = random.Random(args.seed).sample(range(len(population)), args.size)
        sample = [{"id": f"m{k:03d}", **population[i]} for k, i in enumerate(drawn)]
        for mutant in sample:  # the changed line, before and after, for the record
            operator = plugins.get_operator(mutant["operator"])()
            with use_mutation(scratch / mutant["file"], operator, mutant["occurrence"]) as code:
                original, mutated = code
                mutant["applied"] = mutated is not None
                mutant["before"], mutant["after"] = changed_line(original, mutated or original)
        sample_path = args.out / "sample.tsv"
        committed = read_rows(sample_path)
        if committed and [r["before"] + r["after"] for r in committed] != [
            m["before"] + m["after"] for m in sample
        ]:
            print(f"{sample_path} holds another draw: remove it to draw again", file=sys.stderr)
            return 2
        write_rows(sample_path, sample)
        print(f"{len(population)} mutants in the targets; {args.size} drawn with seed {args.seed}")
        if args.draw_only:
            return 0
        unknown = set(args.only or ()) - {m["id"] for m in sample}
        if unknown:
            print(f"--only: no such mutant in the draw: {sorted(unknown)}", file=sys.stderr)
            return 2
        results_path = args.out / "results.tsv"
        done = {r["id"] for r in read_rows(results_path)}
        if "baseline" not in done:  # the unmutated fast tier must pass, or nothing is measured
            status, failed, seconds = run_pytest(scratch, (), 3600.0)
            if status != "survived":
                print(f"the unmutated fast tier does not pass ({status} {failed})", file=sys.stderr)
                return 2
            row = {"id": "baseline", "status": "passes", "seconds": f"{seconds:.0f}",
                   "caught_by": ""}  # fmt: skip
            write_rows(results_path, [row], append=True)
        baseline = next(r for r in read_rows(results_path) if r["id"] == "baseline")
        timeout = args.timeout or max(300.0, 3 * float(baseline["seconds"]))
        every = sorted(
            p.relative_to(scratch).as_posix() for p in (scratch / "tests").glob("test_*.py")
        )
        for mutant in sample:
            if mutant["id"] in done or (args.only and mutant["id"] not in args.only):
                continue
            status, failed, seconds = "not-applied", "", 0.0
            if mutant["applied"]:
                first = targets.first.get(mutant["file"], [])
                order = [*first, *(t for t in every if t not in first and t not in LAST)]
                operator = plugins.get_operator(mutant["operator"])()
                with use_mutation(scratch / mutant["file"], operator, mutant["occurrence"]):
                    status, failed, seconds = run_pytest(scratch, tuple(order), timeout)
            row = {"id": mutant["id"], "status": status, "seconds": f"{seconds:.0f}",
                   "caught_by": failed}  # fmt: skip
            write_rows(results_path, [row], append=True)
            print(f"{mutant['id']} {mutant['file']}:{mutant['line']} {mutant['operator']}: "
                  f"{status} {failed} ({seconds:.0f} s)", flush=True)  # fmt: skip
    finally:
        shutil.rmtree(scratch, ignore_errors=True)

    results = {r["id"]: r for r in read_rows(results_path)}
    counts: dict[str, int] = {}
    for r in results.values():
        if r["id"] == "baseline":
            continue
        key = r["status"]
        if key == "caught" and any(r["caught_by"].startswith(t) for t in LAST):
            key = "caught by lint or drift only"
        counts[key] = counts.get(key, 0) + 1
    summary = [f"{len(population)} mutants in the targets, {args.size} drawn (seed {args.seed})"]
    summary += [f"{status}: {n}" for status, n in sorted(counts.items())]
    (args.out / "summary.txt").write_text("\n".join(summary) + "\n")
    print("\n".join(summary))
    return 0


if __name__ == "__main__":
    start = time.monotonic()
    code = main()
    print(f"({(time.monotonic() - start) / 60:.1f} min)")
    raise SystemExit(code)
