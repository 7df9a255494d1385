"""Compare two configurations, paired: the effect with a 95% t interval, a verdict and a figure.

    python -m a3c_tools.compare agents/a3c_ff.py agents/future_work/a3c_ff_idea.py --out cmp/idea
    python -m a3c_tools.compare agents/a3c_lpq.py agents/future_work/a3c_lpq_growth.py --fast \\
        --lr-range default --runs 15 --out cmp/growth           # chapter 8's design
    python -m a3c_tools.compare agents/a3c_ff.py agents/a3c_ff.py \\
        --other-flags "--activation elu" --expect worse --out cmp/elu   # two flag sets
    python -m a3c_tools.compare --from results/future_work_catch/lpq \\
        results/future_work_catch/lpq_growth                     # two sweeps already run

BASE and OTHER are agent scripts (agents/a3c_*.py, agents/future_work/a3c_*.py, or a copy of
one), or the same script with two flag sets (--base-flags, --other-flags). Each line is a sweep
(a3c_tools.sweep, run in this process) into OUT/base and OUT/other:

    python -m a3c_tools.sweep SCRIPT --out OUT/SIDE --runs N --total-timesteps S --seed SEED \\
        --sample learning-rate=loguniform:LOW:HIGH -- [SIDE's flags] [--envs-per-worker 16] \\
        [--num-workers W] --eval-interval E [--eval-episodes M]

so run i of both lines gets the same learning rate and the same run seed, and the two pair up
by run_id. The defaults are the claims page's budget, the thesis's protocol at a quarter of its
steps: 8 runs per line, 250,000 steps, 1 worker, learning rates log-uniform in [1e-5, 1e-2],
evaluations every S/20 steps (20 per run, as the thesis's 50,000 in 1M) of 50 episodes, a run
scored by the mean of its final 5 evaluations (--score score_all: of all of them). --fast is
chapter 8's setting: 2 workers x 16 envs (the fast setting) and 1,000,000 steps; with
--lr-range default every run has its script's default learning rate (chapter 8's design: the
pairs differ by run seed alone). The two sweeps take turns in rounds of as many runs as run at
once (cores // workers per run locally; all of them on Ray), so that a stopped comparison has
its pairs. --backend ray [--address ...] runs them on a Ray cluster, as the sweep does;
--backend batched [--device cuda] runs each line's runs as one batched program (one worker a
run; both lines are checked to be batchable before either runs).

Looking twice: a comparison that was inconclusive and is then extended (a larger --runs) is
judged again; two looks at 95% each would find an effect that is not there more often than 1 in
20. --second-look gives the second look a 97.5% interval, the claims page's rule (docs/claims.md,
"Two looks"): over both looks the chance is at most 7.5%.

The result: the effect, the mean over the paired runs of (other - base), with its 95% Student-t
interval on the paired differences, and the verdict on the question --expect asks (is other
better than base, the default; worse; or comparable, within +-MARGIN) in the claims page's
terms: one implementation, a3c_tools.paired (its docstring gives the method and why), computes
both, so the same two results give the same numbers here and on docs/claims.md. An inconclusive
result gives the runs per line at which its test would have 80% power, were the true effect and
the spread of the paired differences as measured, at the level the verdict is judged at (0.05;
0.025 with --second-look): a3c_tools.paired.runs_for_power. (The n at which the interval would
just exclude 0 were nothing to change is only about 50% power, half as many.) With fewer than
3 paired runs there is no interval and no verdict (the t interval of 2 is +-12.7 standard
errors); when every run of both lines is at random play (Catch about 0.2, an Atari game's random
score), the result says so and gives no verdict, since neither line learned. A run that failed
or is missing in either line is left out of the pairs. It is printed and written to
OUT/comparison.md, with OUT/comparison.png: both lines' scores against log10 of the learning
rate (against the run seed when all runs share one rate), each run's pair joined by a thin line,
the effect and its interval in the title. --from analyses two sweeps' folders already run (their
results.csv), writing only with --out.

Resuming: the same command again runs only what is missing (each sweep skips its finished runs
and resumes an interrupted one from its checkpoint); when both lines are complete it runs
nothing and prints the result again. A larger --runs extends both lines.

Bad input, checked before anything is created (one line, exit 2): --runs below 3, a script that
is missing or not an agent script, a flag one script lacks or refuses, a flag the comparison
sets itself (the seed, the budget, the evaluation protocol, a sampled learning rate), a budget
too small to evaluate (fewer than 5 evaluations, or evaluations closer than one update of t_max
x K steps), or an OUT whose sweeps were run with another configuration.

Exit codes: 0 a result, 1 fewer than 3 paired runs (runs failed; no interval), 2 bad input, 3 a
run in use elsewhere (resumed by hand: the same command goes on once it is free), 130
interrupted.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import importlib.util
import math
import reprlib
import shlex
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from a3c_tools import AGENTS, figure_sweeps, load_script, paired, parsed_flags, run_main, sweep
from a3c_tools.figure_sweeps import Parser, positive_int
from a3c_tools.plot_sweep import smooth_curve
from a3c_tools.thesis_figures import EVALUATIONS_PER_RUN, eval_interval, lr_range

DEFAULT_RUNS = 8  # the claims page's budget: 8 learning rates x 250k steps x 1 worker
DEFAULT_STEPS = 250_000
DEFAULT_LR_RANGE = (1e-5, 1e-2)  # the range the thesis's bars average over
FAST = {"envs-per-worker": "16", "num-workers": "2"}  # the fast setting: chapter 8's runs
FAST_STEPS = 1_000_000
SIDES = ("base", "other")
REPORT, FIGURE = "comparison.md", "comparison.png"
SCORES = {
    "score": "the mean of the final 5 evaluations",
    "score_all": "the mean of all evaluations",
}
QUESTIONS = {"better": "other better than base", "worse": "other worse than base"}


class UsageError(sweep.UsageError):
    """Bad input: one line, exit 2, nothing created."""


@dataclass
class Line:
    """One side of the comparison: its label, its sweep folder and, when it is run here, the
    sweep's arguments and configuration."""

    side: str
    label: str
    folder: Path
    argv: list[str] | None = None  # the sweep's command line, without --runs
    config: dict | None = None  # its sweep.json

    @property
    def table(self) -> Path:
        return self.folder / sweep.TABLE_NAME


# ------------------------------------------------------------------------------------------------
# The lines to run, checked before anything is created
# ------------------------------------------------------------------------------------------------
def agent_script(text: str, which: str) -> tuple[Path, type]:
    """The path of an agent script and its Args, or UsageError."""
    path = Path(text)
    example = "such as agents/a3c_ff.py or agents/future_work/a3c_lpq_growth.py"
    if not path.is_file():
        raise UsageError(f"{which} {text}: no such file; name an agent script, {example}")
    args_type = sweep.agent_args(path)
    if args_type is None or not hasattr(load_script(path), "AGENT"):
        raise UsageError(
            f"{which} {text} is not an agent script (an Args dataclass, an AGENT and a main "
            f"under `if __name__ == '__main__'`); name one {example}"
        )
    return path, args_type


def label(script: Path, flags: list[str]) -> str:
    """A line's name: its script (from agents/ when inside it) and its own flags."""
    with contextlib.suppress(ValueError):
        script = script.resolve().relative_to(AGENTS)
    return shlex.join([str(script), *flags])


OWNED_HOW = {  # how a comparison sets what a flag set may not
    "learning-rate": "sampled in --lr-range (with --lr-range default, a flag set may set it)",
    "eval-interval": "use --eval-interval",
    "eval-episodes": "use --eval-episodes",
    "num-workers": "use --num-workers (--fast sets 2)",
    "envs-per-worker": "--fast sets 16",
}


def owned_flags(options: argparse.Namespace) -> set[str]:
    """The flags the comparison sets for both lines, which a flag set may not."""
    owned = set(sweep.RESERVED_FLAGS) | {"eval-interval", "eval-episodes"}
    if options.lr_range is not None:
        owned.add("learning-rate")
    if options.fast:
        owned |= set(FAST)
    if options.num_workers is not None:
        owned.add("num-workers")
    return owned


def fixed_flags(flags: list[str], options: argparse.Namespace) -> list[str]:
    """A line's flags after the sweep's `--`: its own, then the comparison's."""
    fixed = list(flags)
    if options.fast:
        fixed += ["--envs-per-worker", FAST["envs-per-worker"]]
    workers = options.num_workers or (int(FAST["num-workers"]) if options.fast else None)
    if workers is not None:
        fixed += ["--num-workers", str(workers)]
    fixed += ["--eval-interval", str(options.eval_interval)]
    if options.eval_episodes is not None:
        fixed += ["--eval-episodes", str(options.eval_episodes)]
    return fixed


def parsed_args(script: Path, args_type: type, flags: list[str], which: str) -> object:
    """The line's Args as its script would parse and check them (tyro, then the runtime's
    checks), or UsageError with tyro's message or the check's."""
    from a3c_runtime import UsageError as FlagError
    from a3c_runtime import resolve_defaults

    import catch_env  # noqa: F401  (registers Catch-v0, as the scripts do)

    try:
        return resolve_defaults(parsed_flags(args_type, flags, prog=script.name))
    except (ValueError, FlagError) as e:
        raise UsageError(f"{which}: {script.name} refuses them: {e}") from None


def check_budget(args: object, options: argparse.Namespace, name: str) -> None:
    """UsageError when the runs could not be scored as the thesis scores them: at least 5
    evaluations after step 0 (SCORE_LAST), each at least one update (t_max x K steps) apart."""
    update = args.t_max * getattr(args, "envs_per_worker", 1)
    interval, steps, last = options.eval_interval, options.steps, sweep.SCORE_LAST
    if interval < update:
        if options.eval_interval_given:
            what, fix = f"--eval-interval {interval} is", f"--eval-interval >= {update}"
        else:
            what = (f"--steps {steps} is too small to evaluate: evaluations every {interval} "
                    "steps (steps / 20) are")  # fmt: skip
            fix = f"--steps >= {EVALUATIONS_PER_RUN * update}"
        raise UsageError(
            f"{what} closer than one update of {name} ({update} steps: --t-max {args.t_max} x "
            f"--envs-per-worker {getattr(args, 'envs_per_worker', 1)}); use {fix}"
        )
    if steps < last * interval:
        raise UsageError(
            f"--steps {steps} is too small to evaluate: a run needs {last} evaluations after "
            f"step 0, every {interval} steps (--eval-interval); use --steps >= {last * interval}"
        )


def planned_lines(options: argparse.Namespace) -> tuple[Line, Line]:
    """The two lines to run, every check made; nothing is created."""
    (base_text, other_text), out = options.scripts, Path(options.out)
    scripts = [agent_script(base_text, "BASE"), agent_script(other_text, "OTHER")]
    (base, _), (other, _) = scripts
    if base.resolve() != other.resolve() and base.name == other.name:
        raise UsageError(
            f"BASE {base_text} and OTHER {other_text} share the file name {base.name}: give the "
            "copy a name of its own (the drift test needs one too)"
        )
    flag_sets = []
    for which, text in (
        ("--base-flags", options.base_flags),
        ("--other-flags", options.other_flags),
    ):
        try:
            flag_sets.append(shlex.split(text))
        except ValueError as e:
            raise UsageError(f"{which} {text!r}: {e}") from None
    if base.resolve() == other.resolve() and flag_sets[0] == flag_sets[1]:
        raise UsageError(
            "BASE and OTHER are the same script with the same flags: tell them apart with "
            "--base-flags or --other-flags"
        )
    owned = owned_flags(options)
    lines = []
    low_high = options.lr_range
    samples = (
        [] if low_high is None else [f"learning-rate=loguniform:{low_high[0]:g}:{low_high[1]:g}"]
    )
    for side, which, (script, args_type), flags in zip(
        SIDES, ("--base-flags", "--other-flags"), scripts, flag_sets, strict=True
    ):
        for name in sorted(owned):
            if any(sweep.flag_value(flags, spelling) is not None
                   for spelling in (name, name.replace("-", "_"))):  # fmt: skip
                how = OWNED_HOW.get(name, "the sweep sets it for each run")
                raise UsageError(
                    f"{which} sets --{name}, which the comparison sets for both: {how}"
                )
        fixed = fixed_flags(flags, options)
        sweep.check_flags(
            script, [sweep.parse_sample(s) for s in samples], fixed, options.steps, which
        )
        example = ["--learning-rate", f"{low_high[0]:g}"] if low_high else []
        args = parsed_args(script, args_type, [*fixed, *example], which)
        check_budget(args, options, script.name)
        argv = [str(script), "--out", str(out / side), "--total-timesteps", str(options.steps),
                "--seed", str(options.seed)]  # fmt: skip
        for sample in samples:
            argv += ["--sample", sample]
        argv += ["--backend", options.backend]
        if options.backend == "batched":
            argv += ["--device", options.device]
        for flag, value in (("--address", options.address), ("--cpus", options.cpus),
                            ("--max-concurrent", options.max_concurrent)):  # fmt: skip
            if value is not None:
                argv += [flag, str(value)]
        argv += ["--", *fixed]
        sweep_args, sweep_fixed = sweep.parse_args([*argv[:1], "--runs", "1", *argv[1:]])
        config = sweep.configuration(sweep_args, sweep_fixed)
        mismatch = sweep.config_mismatch(out / side, config)
        if mismatch:
            raise UsageError(mismatch)
        # both lines' runs checked before either runs, as each run checks itself at its start
        runs = sweep.plan_runs(config, options.runs)
        runs_args = sweep.checked_run_args(str(script), runs, out / side, options.backend)
        if options.backend == "batched":
            sweep.check_batched(sweep_args, runs_args)
        lines.append(Line(side, label(script, flags), out / side, argv, config))
    if options.backend == "ray" and importlib.util.find_spec("ray") is None:
        raise UsageError(sweep.RAY_MISSING)
    return lines[0], lines[1]


# ------------------------------------------------------------------------------------------------
# Running: the two sweeps in turns
# ------------------------------------------------------------------------------------------------
def run_ids(line: Line, runs: int) -> list[str]:
    """The run ids of the line's runs 0..runs-1, as its sweep names them."""
    return [run.run_id for run in sweep.plan_runs(line.config, runs)]


def complete(line: Line, runs: int) -> bool:
    """Whether the line's table holds runs 0..runs-1 (ok or failed)."""
    table = sweep.ResultsTable(line.table, [])
    return all(table.finished(run_id) for run_id in run_ids(line, runs))


def round_size(lines: tuple[Line, Line], options: argparse.Namespace) -> int:
    """How many runs of a line run at once: a round of each line in turn."""
    if options.backend in ("ray", "batched"):  # (batched: a line's runs are one program)
        return options.runs
    workers = max(sweep.plan_runs(line.config, 1)[0].workers for line in lines)
    return max(1, (options.cpus or sweep.cpu_count()) // workers)


def run_lines(lines: tuple[Line, Line], options: argparse.Namespace) -> int:
    """Sweep both lines to --runs in turns; 0, or the exit code that stopped it (2, 3, 130: a
    sweep's refusal is its one line)."""
    step = round_size(lines, options)
    try:
        for target in [*range(step, options.runs, step), options.runs]:
            for line in lines:
                if complete(line, target):
                    continue
                print(f"== {line.side}: {line.label}, runs 0-{target - 1}", flush=True)
                args, fixed = sweep.parse_args([*line.argv[:1], "--runs", str(target),
                                                *line.argv[1:]])  # fmt: skip
                code = sweep.sweep(args, fixed)
                if code in (2, sweep.IN_USE_EXIT, 130):
                    return code
    except KeyboardInterrupt:  # between two sweeps: each sweep handles its own
        return 130
    except sweep.UsageError as e:  # what a line's folder holds (a checkpoint not its run's)
        print(f"error: {e}", file=sys.stderr)
        return 2
    return 0


# ------------------------------------------------------------------------------------------------
# The result
# ------------------------------------------------------------------------------------------------
def answer(call: str, effect: float, expect: str, margin: float) -> str:
    """The verdict in plain words: better, worse, comparable, or inconclusive with the runs per
    line for 80% power, and the claims page's verdict on the question asked."""
    question = QUESTIONS.get(expect, f"other within +-{margin:g} of base")
    head = call.partition(":")[0]
    if head in ("inconclusive", "no verdict"):
        return f"{call} (expecting {question})"
    if expect == "comparable":
        word = "comparable" if head == "reproduced" else (
            f"{'better' if effect > 0 else 'worse'} by more than {margin:g}")  # fmt: skip
    else:
        word = expect if head == "reproduced" else {"better": "worse", "worse": "better"}[expect]
    return f"{word} (expecting {question}: {head})"


def learning_rates(line: Line) -> dict[str, float]:
    """run_id -> the run's sampled learning rate, where its table has one."""
    rows = paired.read_rows(line.folder, sweep.TABLE_NAME)
    return {row["run_id"]: float(row["learning-rate"]) for row in rows if row.get("learning-rate")}


def config_of(line: Line) -> dict | None:
    if line.config is not None:
        return line.config
    path = line.folder / sweep.CONFIG_NAME
    if not path.is_file():
        return None
    return sweep.read_config(path, ("script", "fixed_flags"))  # UsageError if not a sweep's


def env_of(line: Line) -> str:
    """The env id the line's runs played: its sweep's --env, else the scripts' Catch-v0."""
    config = config_of(line) or {}
    return sweep.flag_value(list(config.get("fixed_flags") or []), "env") or paired.CATCH


def describe(line: Line) -> str:
    """The line's configuration as its sweep ran it: script, flags and steps."""
    config = config_of(line)
    if config is None:
        return "(no sweep.json)"
    steps = config.get("total_timesteps")
    budget = ["--total-timesteps", str(steps)] if steps else []
    return f"`{shlex.join([config['script'], *config['fixed_flags'], *budget])}`"


def report(
    lines: tuple[Line, Line],
    result: paired.Paired,
    considered: list[str],
    options: argparse.Namespace,
    command: str,
) -> str:
    """The comparison in Markdown: both lines, the effect, the verdict, the design."""
    base_ok, other_ok = (paired.read_scores(line.table, options.score) for line in lines)
    counts = [sum(run_id in ok for run_id in considered) for ok in (base_ok, other_ok)]
    out = [f"# {lines[1].label} against {lines[0].label}", ""]
    out += ["| line | configuration | runs ok | mean +- s.e. (paired runs) |",
            "|---|---|---:|---:|"]  # fmt: skip
    for line, ok, scores in zip(lines, counts, (result.base, result.other), strict=True):
        error = scores.std(ddof=1) / math.sqrt(len(scores))
        out.append(f"| {line.side}: {line.label} | {describe(line)} | {ok} of {len(considered)} "
                   f"| {scores.mean():.3f} +- {error:.3f} |")  # fmt: skip
    left_out = [run_id for run_id in considered if run_id not in result.run_ids]
    call = result.verdict(options.expect, options.margin)
    out += [
        "",
        f"Effect (other - base, {SCORES[options.score]}): **{result.shown()}**, the mean over "
        f"{result.runs} paired runs with its {result.level} interval (Student t on the paired "
        "differences)"
        + (f" (left out, failed or missing in a line: {', '.join(left_out)})" if left_out else "")
        + ".",
        "",
        f"Verdict: **{answer(call, result.effect, options.expect, options.margin)}**.",
    ]
    config = config_of(lines[0]) or {}
    samples = ", ".join(config.get("samples") or []) or "none, the scripts' default learning rate"
    seed = config.get("seed", "?")
    out += [
        "",
        f"Design: sweep seed {seed}, so run i has run seed {seed} + {sweep.SEED_STRIDE} i and "
        f"the same sampled values in both lines (samples: {samples}).",
    ]
    out += ["", f"Command: `{command}`"]
    return "\n".join(out) + "\n"


def draw(lines: tuple[Line, Line], result: paired.Paired, png: Path, title: str) -> None:
    """Both lines' scores against log10(learning rate), each run's pair joined by a thin line;
    against the run when the runs share one learning rate."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rates = learning_rates(lines[0])
    x = np.array([rates.get(run_id, np.nan) for run_id in result.run_ids])
    swept = bool(np.isfinite(x).all() and len(np.unique(x)) > 1)
    x = np.log10(x) if swept else np.arange(result.runs, dtype=float)
    with plt.style.context("ggplot"):
        fig, ax = plt.subplots(figsize=(9, 6), constrained_layout=True)
        colors = plt.rcParams["axes.prop_cycle"].by_key()["color"]
        for xi, b, o in zip(x, result.base, result.other, strict=True):
            ax.plot([xi, xi], [b, o], color="0.45", linewidth=0.8, zorder=1)
        for i, (line, scores) in enumerate(zip(lines, (result.base, result.other), strict=True)):
            color = colors[i]
            ax.scatter(x, scores, s=30, color=color, zorder=2, label=f"{line.side}: {line.label}")
            if swept:
                curve_x, curve_y = smooth_curve(x, scores, (x.min(), x.max()))
                ax.plot(curve_x, curve_y, color=color, linewidth=2.5, alpha=0.8)
        if swept:
            ax.set_xlabel("log10(learning rate)")
        else:
            ax.set_xticks(x, [str(int(i)) for i in x])
            ax.set_xlabel("run (the same learning rate and seed in both lines)")
        ax.set_ylabel("score")
        ax.legend(loc="best", framealpha=0.0)
        ax.set_title(title, fontsize=11)
        fig.savefig(png, dpi=100)
        plt.close(fig)


def analyse(
    lines: tuple[Line, Line],
    considered: list[str] | None,
    options: argparse.Namespace,
    out: Path | None,
    command: str,
) -> int:
    """Pair the lines' runs (those in `considered`, else all), print the result, write it."""
    scores = [paired.read_scores(line.table, options.score) for line in lines]
    if considered is None:
        considered = sorted(set(scores[0]) | set(scores[1]))
    scores = [{k: v for k, v in s.items() if k in considered} for s in scores]
    confidence = paired.SECOND_LOOK if options.second_look else paired.CONFIDENCE
    result = paired.pair(*scores, confidence=confidence, env_id=env_of(lines[0]))
    if result is None:
        print(f"fewer than {paired.MIN_PAIRS} paired runs (ok in both lines): no interval and no "
              f"verdict; see {lines[0].table} and {lines[1].table}", file=sys.stderr)  # fmt: skip
        return 1
    text = report(lines, result, considered, options, command)
    sys.stdout.write(text)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        (out / REPORT).write_text(f"{text}\n![comparison]({FIGURE})\n")
        call = result.verdict(options.expect, options.margin).partition(":")[0]
        title = f"other - base: {result.shown()} ({result.level}, {result.runs} pairs); {call}"
        draw(lines, result, out / FIGURE, title)
        print(f"wrote {out / REPORT}, {out / FIGURE}")
    return 0


# ------------------------------------------------------------------------------------------------
# Command line
# ------------------------------------------------------------------------------------------------
def positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be > 0, got {text}")
    return value


def lr_range_or_default(text: str) -> tuple[float, float] | str:
    return text if text == "default" else lr_range(text)


RUN_OPTIONS = ("runs", "steps", "fast", "lr_range", "seed", "base_flags", "other_flags",
               "eval_interval", "eval_episodes", "num_workers", "backend", "device", "address",
               "cpus", "max_concurrent")  # fmt: skip


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = Parser(
        prog="python -m a3c_tools.compare",
        usage="%(prog)s BASE OTHER --out OUT [options]\n"
        "       %(prog)s --from BASE_SWEEP OTHER_SWEEP [--out OUT] [--score ...] [--expect ...]",
        description="Compare two agent scripts, or one script with two flag sets, at the same "
        "learning rates and run seeds: the paired effect with a 95% t interval, the verdict "
        "and a figure. See the module docstring for more.",
    )
    parser.add_argument("scripts", nargs="*", metavar="BASE OTHER", help="the two agent scripts")
    parser.add_argument(
        "--from",
        dest="from_",
        nargs=2,
        metavar=("BASE_SWEEP", "OTHER_SWEEP"),
        help="analyse two sweep folders already run (their results.csv)",
    )
    parser.add_argument("--out", default=None, help="the comparison's folder (OUT/base, "
                        "OUT/other, comparison.md, comparison.png)")  # fmt: skip
    parser.add_argument("--runs", type=positive_int, default=None,
                        help=f"runs per line, >= {paired.MIN_PAIRS} "
                        f"(default {DEFAULT_RUNS})")  # fmt: skip
    parser.add_argument(
        "--steps",
        type=positive_int,
        default=None,
        help=f"steps per run (default {DEFAULT_STEPS:,}; {FAST_STEPS:,} with --fast)",
    )
    parser.add_argument("--fast", action="store_true", default=None,
                        help="the fast setting, chapter 8's: --envs-per-worker 16 --num-workers 2, "
                        "1M steps")  # fmt: skip
    parser.add_argument("--lr-range", type=lr_range_or_default, default=None, metavar="LOW:HIGH",
                        help="learning rates log-uniform in [LOW, HIGH] (default 1e-5:1e-2); "
                        "'default': every run at its script's default")  # fmt: skip
    parser.add_argument(
        "--seed",
        type=int,
        default=None,
        help="the sweep seed: run i's learning rate and seed (default 1)",
    )
    for side in ("base", "other"):
        parser.add_argument(f"--{side}-flags", default=None, metavar="FLAGS",
                            help=f"{side.upper()}'s own flags, quoted: \"--t-max 10\" (one flag "
                            f"without a value: --{side}-flags=--no-anneal-lr)")  # fmt: skip
    parser.add_argument("--score", choices=sorted(SCORES), default="score",
                        help="score: the mean of the final 5 evaluations (the thesis's); "
                        "score_all: the mean of all of them")  # fmt: skip
    parser.add_argument("--expect", choices=paired.EXPECTS, default="better",
                        help="the question: is OTHER better than BASE (default), worse, or "
                        "comparable within --margin")  # fmt: skip
    parser.add_argument(
        "--margin",
        type=positive_float,
        default=paired.MARGIN,
        help=f"comparable means within +-MARGIN (default {paired.MARGIN:g})",
    )
    parser.add_argument(
        "--second-look",
        action="store_true",
        help=f"this result looks again at lines extended after an inconclusive one: a "
        f"{100 * paired.SECOND_LOOK:g}%% interval (the claims page's rule for two looks)",
    )
    parser.add_argument(
        "--eval-interval",
        type=positive_int,
        default=None,
        help="steps between evaluations (default: steps / 20, the thesis's)",
    )
    parser.add_argument(
        "--eval-episodes",
        type=positive_int,
        default=None,
        help="episodes per evaluation (default: the scripts' 50, the thesis's)",
    )
    parser.add_argument(
        "--num-workers",
        type=positive_int,
        default=None,
        help="workers per run (default 1; 2 with --fast; the thesis ran 12)",
    )
    figure_sweeps.add_backend_arguments(parser, batched=True, default=None, concurrent=True)
    options = parser.parse_args(argv)
    options.argv = list(argv)
    if options.from_ is not None:
        given = [name for name in RUN_OPTIONS if getattr(options, name) is not None]
        if options.scripts or given:
            extra = ["BASE OTHER"] if options.scripts else []
            extra += [f"--{name.replace('_', '-')}" for name in given]
            parser.error(f"--from analyses sweeps already run: {', '.join(extra)} do not apply")
        return options
    if len(options.scripts) != 2:
        parser.error(f"name two agent scripts, BASE and OTHER (got {len(options.scripts)})")
    if options.out is None:
        parser.error("the following arguments are required: --out")
    options.runs = options.runs or DEFAULT_RUNS
    if options.runs < paired.MIN_PAIRS:
        parser.error(
            f"--runs must be >= {paired.MIN_PAIRS} (got {options.runs}): fewer paired runs give "
            "no useful interval and no verdict"
        )
    options.fast = bool(options.fast)
    options.steps = options.steps or (FAST_STEPS if options.fast else DEFAULT_STEPS)
    if options.lr_range is None:
        options.lr_range = DEFAULT_LR_RANGE
    elif options.lr_range == "default":  # every run at its script's default learning rate
        options.lr_range = None
    options.seed = 1 if options.seed is None else options.seed
    options.base_flags = options.base_flags or ""
    options.other_flags = options.other_flags or ""
    options.eval_interval_given = options.eval_interval is not None
    options.eval_interval = options.eval_interval or eval_interval(options.steps)
    options.backend = options.backend or "local"
    if options.address and options.backend != "ray":
        parser.error("--address needs --backend ray")
    if options.device is not None and options.backend != "batched":
        parser.error("--device needs --backend batched")
    options.device = options.device or "cpu"
    return options


def from_lines(options: argparse.Namespace) -> tuple[Line, Line]:
    """The two sweep folders of --from, checked: each holds a results.csv, and they pair."""
    lines = []
    for side, text in zip(SIDES, options.from_, strict=True):
        folder = Path(text)
        if not (folder / sweep.TABLE_NAME).is_file():
            raise UsageError(f"--from {text}: no {sweep.TABLE_NAME} there; name two sweep folders")
        lines.append(Line(side, text.rstrip("/"), folder))
        check_table(lines[-1].table, options.score)
    configs = [config_of(line) for line in lines]
    if all(configs):
        for key in ("seed", "samples"):
            if configs[0].get(key) != configs[1].get(key):
                values = f"{configs[0].get(key)!r} and {configs[1].get(key)!r}"
                raise UsageError(
                    f"--from: the two sweeps do not pair: their {key} differ ({values}), so run "
                    "i is not the same learning rate and seed in both"
                )
    return lines[0], lines[1]


def check_table(table: Path, column: str) -> None:
    """UsageError, in one line, for a results.csv that --from cannot read: not a sweep's (no
    run_id, status or `column` column; not a CSV table), or a run whose score (an ok run's) or
    learning rate is not a finite number."""
    try:
        with open(table, newline="") as f:
            reader = csv.DictReader(f)
            header = reader.fieldnames or []
            missing = [name for name in ("run_id", "status", column) if name not in header]
            if missing:
                raise UsageError(f"{table} is not a sweep's table: no {', '.join(missing)} column")
            for row in reader:
                used = [column] if row["status"] == "ok" else []
                used += ["learning-rate"] if row.get("learning-rate") else []
                for name in used:
                    if not is_finite_number(row[name]):
                        raise UsageError(
                            f"{table}: run {reprlib.repr(row['run_id'])}: its {name} is "
                            f"{reprlib.repr(row[name])}, not a number"
                        )
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise UsageError(f"{table} is not a sweep's table: {e}") from None


def is_finite_number(text: str | None) -> bool:
    try:
        return math.isfinite(float(text))
    except (TypeError, ValueError):
        return False


def main(argv: list[str] | None = None) -> int:
    options = parse_args(sys.argv[1:] if argv is None else argv)
    command = shlex.join(["python", "-m", "a3c_tools.compare", *options.argv])
    try:
        if options.from_ is not None:
            lines = from_lines(options)
            out = Path(options.out) if options.out else None
            return analyse(lines, None, options, out, command)
        lines = planned_lines(options)
    except sweep.UsageError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    code = run_lines(lines, options)
    if code == 130:
        print("interrupted: the same command resumes the comparison", flush=True)
        return 130
    if code:
        return code
    considered = run_ids(lines[0], options.runs)  # not the runs of an earlier, larger --runs
    return analyse(lines, considered, options, Path(options.out), command)


if __name__ == "__main__":
    run_main(main)
