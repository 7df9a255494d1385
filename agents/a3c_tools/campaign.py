"""A campaign: a fixed plan of sweeps, run in priority order over as many sessions as it takes.

    python -m a3c_tools.campaign results/campaign/plan.toml            # run what is left of it
    python -m a3c_tools.campaign results/campaign/plan.toml --status   # progress only, no run
    python -m a3c_tools.campaign results/campaign/plan.toml --dry-run  # the commands it would run

The plan (TOML; results/campaign/plan.toml is the thesis's, and its header gives the format) is
a list of items, each a list of sweeps, decided before the first run so that no verdict is
tuned to the data. The campaign runs the items in their order, and in each its sweeps, through
a3c_tools.sweep and a3c_tools.atari_figures: a run already in a sweep's results.csv is skipped,
one that was cut off resumes from its checkpoint, so the command is the same in every session
and stopping it (Ctrl-C, SIGTERM, the session's end) loses at most the runs in flight.

Four kinds of item:
- extend: each of its lines (a committed sweep folder) grows to `runs` runs with the line's own
  configuration, read from its sweep.json, so runs 0..k-1 are kept and run i draws what it drew
  before (sweep.py's seeding); but for the flags that would send the runs' data elsewhere
  (--track, --wandb-entity, --wandb-project-name), which a campaign never takes from a file (a
  sweep.json or the plan): a line says so, and its runs go untracked;
- repeat: run 0 (or the item's `run`) of a committed line again into a scratch folder and
  compare its score with the committed one (with one worker a run is exactly repeatable, so a
  difference means the code computes something else than when the line was made), and say
  whether the two agree within the item's `agree_within` where it names one;
- sweep: new lines whose configuration the plan gives in full (each line's script, out and
  flags; the item's runs, seed, total_timesteps, samples and flags shared by its lines, so runs
  pair up by run_id), as a pre-registered study needs;
- atari: atari_figures lines of one figure and game over `seeds` seeds of `steps` steps (run
  seeds `seed`, `seed` + 1000, ...: atari_figures' 1, 1001, ... unless the item names one); after
  each of its sweeps the figure is drawn again (`atari_figures FIG --plot-only`), which writes
  the figure's results.csv that the claims page's Atari rows read. Its runs take the Atari
  command's `--precision auto` (bf16 at 16 envs a worker on a CPU with native bf16, fp32
  elsewhere); `needs_native_bf16 = true` runs the item only on a CPU with native bf16 (elsewhere
  a line says so and the item waits), so that a line's runs do not change precision with the
  host.

Each sweep invocation has a row in SWEEPS.tsv beside the plan: its item, folder, start and end
(UTC), wall time, the runs it held before and after, and the CPU model (with ", native
bf16" where it has it) and cores that ran it;
the row is written when the sweep starts and kept current while it runs, so a campaign killed
outright loses at most a minute of it. A SIGTERM while a sweep runs stops it cleanly (its runs
checkpoint) and the campaign with it (exit 130).
After each sweep, and with --status, the progress (runs done of the plan, CPU-hours spent on
the plan's new runs, an estimate of those left, and the runs begun but unfinished) is written to
PROGRESS.md beside the plan.
CPU-hours are wall time x workers, from the sweeps' results.csv; a run not yet made is
estimated from its line's finished runs, or from the item's `cpu_hours_per_run` (or its
`rate_from` lines' committed steps/s, as a3c_tools.confirmatory estimates them), less the share
of its steps that its checkpoint holds where it has begun (here or on another machine).

Where the runs run is the command's, not the plan's (but for a sweep item's line that names
`backend = "batched"`, a study of the backends themselves: it runs batched on --device, cpu by
default): `--backend batched --device cuda` runs
each Catch sweep of a script the batched backend takes (a3c_runtime.batchable.BATCHED_SCRIPTS) as
one batched program on the GPU, and every other sweep (Atari, the future-work scripts) on
the process backend as before; SWEEPS.tsv names the device of a batched sweep. A line may so
hold runs of both backends: run i is the same run on either (tests/test_batched.py), but for the
order of floating-point sums. A batched sweep's runs share one wall clock and one core (or
device), so a run of it costs its wall time over the line's runs (their batch) in PROGRESS.md.
`--batchable-last` (on a CPU) runs
those Catch sweeps after every other sweep of the plan, so that the CPU first does what a GPU
could not batch while a device, when one is lent, runs the rest; the order of the runs changes
nothing in a plan's analysis, which waits for all of them.

A plan is checked before anything runs: every script it names must be one of the clone's agent
scripts (agents/a3c_*.py, agents/future_work/a3c_*.py) and every folder (out, source,
config_from, rate_from) must lie under the clone's results/, so that a plan handed on can
neither run other code nor write or read outside the repository's results.

Exit codes: 0 when the plan is done, 1 when a sweep failed, 2 for a bad plan or options
(nothing runs), 130 when interrupted.
"""

from __future__ import annotations

import argparse
import calendar
import csv
import dataclasses
import os
import platform
import shlex
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from a3c_tools import ROOT, agent_script, read_toml, results_folder, run_main
from a3c_tools import atari_figures as af
from a3c_tools.figure_sweeps import DataError, Parser, execute
from a3c_tools.paired import read_rows
from a3c_tools.sweep import UsageError as SweepUsageError
from a3c_tools.sweep import cpu_count, read_config, split_elsewhere

KINDS = ("extend", "repeat", "atari", "sweep")
ALL = "**all**"  # the progress table's last row
LOG_EVERY_S = 60.0  # how often a running sweep's SWEEPS.tsv row is brought up to date


@dataclass(frozen=True)
class Sweep:
    """One sweep of the plan: its folder, the runs it must have, and the command that makes
    them (without the interpreter)."""

    out: Path
    runs: int
    command: list[str]
    first_look: int  # runs the folder held when the plan was fixed (not the campaign's)
    source: Path  # the committed line whose runs estimate the cost of this one's


@dataclass(frozen=True)
class Item:
    id: str
    kind: str
    title: str
    sweeps: list[Sweep]
    cpu_hours_per_run: float | None
    draw: list[str] | None = None  # an atari item's figure, drawn after each of its sweeps
    needs_native_bf16: bool = False  # its runs only where --precision auto gives bf16 (below)


def flag_value(words: list[str], *names: str) -> str | None:
    """The value after the first of `names` in a command's words, or None if none is there."""
    for flag, value in zip(words, words[1:], strict=False):
        if flag in names:
            return value
    return None


def cpu_hours(row: dict) -> float:
    """A run's CPU-hours: its wall time times its workers (its --num-workers, else 1)."""
    value = flag_value(shlex.split(row.get("flags") or ""), "--num-workers", "--num_workers")
    return float(row["wall_time_s"] or 0) * (1 if value is None else int(value)) / 3600


def begun_steps(sweep: Sweep, rows: list[dict]) -> list[int]:
    """The steps that the plan's begun, unfinished runs of a sweep have done: their run folders'
    checkpoints' global steps (a run begun on another machine and unpacked here counts too)."""
    finished = {row["run_id"] for row in rows}
    steps = []
    for index in range(sweep.first_look, sweep.runs):
        run = f"run-{index:04d}"
        path = sweep.out / "runs" / run / "checkpoint.pt"
        if run in finished or not path.is_file():
            continue
        from a3c_runtime.checkpoints import checkpoint_step  # torch: only where a run has begun

        step = checkpoint_step(path)
        if step is not None:
            steps.append(step)
    return steps


def extend_command(script: str, out: Path, runs: int, where: str, source: Path) -> list[str]:
    """The sweep.py command that grows a line in `out` to `runs` runs with the configuration of
    the committed line in `source` (its sweep.json)."""
    config_path = source / "sweep.json"
    if not config_path.is_file():
        raise DataError(f"{where}: {source} has no sweep.json")
    try:  # each field used below there, of its type
        config = read_config(config_path, ("script", "samples", "fixed_flags", "seed"))
    except SweepUsageError as e:
        raise DataError(f"{where}: {e}") from None
    if Path(script).name != config.get("script"):
        raise DataError(f"{where}: {source} is a sweep of {config['script']}, not {script}")
    command = ["-m", "a3c_tools.sweep", script, "--out", str(out), "--runs", str(runs)]
    command += ["--seed", str(config["seed"])]
    if config.get("total_timesteps") is not None:
        command += ["--total-timesteps", str(config["total_timesteps"])]
    for sample in config["samples"]:
        command += ["--sample", sample]
    return command + ["--", *not_elsewhere(config["fixed_flags"], where, str(config_path))]


def not_elsewhere(flags: list, where: str, source: str) -> list:
    """flags less those that would send the runs' data elsewhere (sweep.split_elsewhere: W&B
    tracking, its entity and project), which a file handed on (a sweep.json, the plan) never
    sets; a line on stderr says so where there were any."""
    kept, elsewhere = split_elsewhere(flags)
    if elsewhere:
        shown = shlex.join(map(str, elsewhere)).encode("unicode_escape").decode()
        print(f"note: {where}: {source} would send the runs' data elsewhere ({shown}); a "
              "campaign takes that from no file: its runs go untracked", file=sys.stderr,
              flush=True)  # fmt: skip
    return kept


def read_item(entry: dict, index: int, plan: Path) -> Item:
    """A plan's [[item]], or DataError in one line: a plan is a file someone may hand on, so any
    field missing or of another kind is a malformed plan, never a traceback."""
    where = f"{plan}: item {index + 1}"
    if not isinstance(entry, dict):
        raise DataError(f"{where} is not a table")
    try:
        return item_of(entry, where)
    except (DataError, SweepUsageError):  # said in one line already
        raise
    except KeyError as missing:
        raise DataError(f"{where} has no {missing.args[0]}") from None
    except (TypeError, ValueError, AttributeError, OverflowError) as error:
        raise DataError(f"{where}: a field of another kind ({error})") from None


def item_of(entry: dict, where: str) -> Item:
    """read_item's work: KeyError, TypeError and ValueError, where a field is missing or not
    what it should be, are read_item's to say."""
    kind, item_id, title = entry["kind"], entry["id"], entry["title"]
    if kind not in KINDS:
        raise DataError(f"{where}: kind {kind!r}; valid: {', '.join(KINDS)}")
    try:  # a plan's scripts are the clone's agent scripts, its folders under results/
        for part in (entry, *entry.get("lines", [])):
            if isinstance(part, dict) and "script" in part:
                agent_script(part["script"])
            for key in ("out", "source", "config_from"):
                if isinstance(part, dict) and key in part:
                    results_folder(part[key])
        for folder in entry.get("rate_from", []):
            results_folder(folder)
    except ValueError as error:
        raise DataError(f"{where}: {error}") from None
    sweeps = []
    if kind == "extend":
        for line in entry.get("lines", []):
            out = Path(line["out"])
            source = Path(line.get("config_from", line["out"]))
            command = extend_command(line["script"], out, int(entry["runs"]), where, source)
            first_look = int(line.get("first_look", 0))
            sweeps.append(Sweep(out, int(entry["runs"]), command, first_look, source))
    elif kind == "sweep":  # a new line, its configuration in the plan itself
        for line in entry.get("lines", []):
            script = line["script"]
            out = Path(line["out"])
            command = ["-m", "a3c_tools.sweep", script, "--out", str(out),
                       "--runs", str(int(entry["runs"])), "--seed", str(int(entry["seed"])),
                       "--total-timesteps", str(int(entry["total_timesteps"]))]  # fmt: skip
            for sample in entry.get("samples", []):
                command += ["--sample", sample]
            backend = line.get("backend", "local")  # a study of the backends names them
            if backend not in ("local", "batched"):
                raise DataError(f"{where}: backend {backend!r}; valid: local, batched")
            if backend == "batched":  # its device is the campaign's --device
                command += ["--backend", "batched", "--device", "cpu"]
            flags = [*line.get("flags", []), *entry.get("flags", [])]
            command += ["--", *not_elsewhere(flags, where, "the plan")]
            sweeps.append(Sweep(out, int(entry["runs"]), command, 0, out))
    elif kind == "repeat":
        scratch, runs = Path(entry["out"]), int(entry.get("run", 0)) + 1  # runs 0..run
        command = extend_command(entry["script"], scratch, runs, where, Path(entry["source"]))
        sweeps.append(Sweep(scratch, runs, command, 0, Path(entry["source"])))
    else:
        figure = af.by_id(entry["figure"])
        options = argparse.Namespace(
            out=entry["out"], steps=int(entry["steps"]), backend="local", address=None,
            cpus=None, eval_interval=af.EVAL_INTERVAL, eval_episodes=af.EVAL_EPISODES,
            num_workers=int(entry["num_workers"]), seed=int(entry.get("seed", af.SEED)),
        )  # fmt: skip
        lines = {line.slug: line for line in figure.lines}
        if entry["game"] not in figure.games:
            raise DataError(f"{where}: {figure.id} has no game {entry['game']!r}; "
                            f"valid: {', '.join(figure.games)}")  # fmt: skip
        for slug in entry["lines"]:
            if slug not in lines:
                raise DataError(f"{where}: {figure.id} has no line {slug}; valid: {list(lines)}")
            line, game, seeds = lines[slug], entry["game"], int(entry["seeds"])
            command = af.sweep_command(figure, game, line, options, seeds)
            out = af.line_folder(Path(entry["out"]), figure, game, line)
            sweeps.append(Sweep(out, seeds, command, 0, out))
    if not sweeps:
        raise DataError(f"{where} has no sweep")
    per_run = entry.get("cpu_hours_per_run")
    if per_run is None and "rate_from" in entry:  # a study's plan: its estimate, run by run
        from a3c_tools.confirmatory import cpu_hours

        try:
            per_run = cpu_hours(entry) / (len(sweeps) * max(sweep.runs for sweep in sweeps))
        except (OSError, KeyError, ValueError, ZeroDivisionError) as error:
            raise DataError(f"{where}: rate_from: no committed runs' rate ({error})") from None
    draw = None
    if kind == "atari":  # the figure's results.csv is what the claims page's Atari rows read
        draw = ["-m", "a3c_tools.atari_figures", entry["figure"], "--out", entry["out"],
                "--plot-only"]  # fmt: skip
    needs = entry.get("needs_native_bf16", False)
    if not isinstance(needs, bool):
        raise DataError(f"{where}: needs_native_bf16 must be true or false (got {needs!r})")
    per_run = None if per_run is None else float(per_run)
    return Item(item_id, kind, title, sweeps, per_run, draw, needs)


def load_plan(plan: Path) -> list[Item]:
    try:
        data = read_toml(plan)
    except ValueError as error:
        raise DataError(str(error)) from None
    items = [read_item(e, i, plan) for i, e in enumerate(data.get("item", []))]
    ids = [item.id for item in items]
    if len(set(ids)) != len(ids):
        raise DataError(f"{plan}: item ids repeat: {ids}")
    return items


def item_clocks(log: Path) -> dict[str, tuple[float, list[str]]]:
    """item id -> (its wall time in hours, the CPUs that ran it), from SWEEPS.tsv: the wall time
    is the union of its sweep invocations' spans (sweeps run side by side count once); ALL's
    is the union of every item's."""
    spans: dict[str, list[tuple[float, float]]] = {}
    cpus: dict[str, list[str]] = {}
    if log.is_file():
        with log.open(newline="") as f:
            for row in csv.DictReader(f, delimiter="\t"):
                start, end = (calendar.timegm(time.strptime(row[k], "%Y-%m-%d %H:%M:%S"))
                              for k in ("started_utc", "ended_utc"))  # fmt: skip
                spans.setdefault(row["item"], []).append((start, end))
                cpu = f"{row['cpu']} ({row['cores']} cores)"
                if cpu not in cpus.setdefault(row["item"], []):
                    cpus[row["item"]].append(cpu)
    spans[ALL] = [span for item_spans in list(spans.values()) for span in item_spans]
    cpus[ALL] = list(dict.fromkeys(cpu for item_cpus in cpus.values() for cpu in item_cpus))
    clocks = {}
    for item, item_spans in spans.items():
        total, reached = 0.0, float("-inf")
        for start, end in sorted(item_spans):
            total += max(0.0, end - max(start, reached))
            reached = max(reached, end)
        clocks[item] = (total / 3600, cpus[item])
    return clocks


def progress(items: list[Item], log: Path | None = None) -> tuple[str, bool]:
    """The progress table (markdown) and whether every sweep of the plan is done; with `log`
    (SWEEPS.tsv), each item's wall time and CPUs too."""
    clocks = item_clocks(log) if log is not None else {}
    lines = ["| item | runs done of plan | CPU-hours spent | CPU-hours left (est.) | wall time "
             "(hours) | CPUs | runs begun, unfinished (their steps done) |",
             "|---|---|---|---|---|---|---|"]  # fmt: skip
    total_done = total_plan = total_begun = 0
    total_spent = total_left = 0.0
    seen: set[Path] = set()
    for item in items:
        done = plan = 0
        spent = left = 0.0
        begun: list[float] = []  # each begun run's share of its budget done
        for sweep in item.sweeps:
            if sweep.out in seen:  # a line shared by two items counts once, in the first
                continue
            seen.add(sweep.out)
            rows = read_rows(sweep.out)
            new_rows = rows[sweep.first_look :][: sweep.runs - sweep.first_look]
            cost = [cpu_hours(r) for r in rows]
            if flag_value(sweep.command, "--backend") == "batched":  # one core: its runs' clock
                cost = [c / max(sweep.runs, 1) for c in cost]  # (a batch of the line's runs)
            known = cost or [cpu_hours(r) for r in read_rows(sweep.source)]
            per_run = sum(known) / len(known) if known else (item.cpu_hours_per_run or 0.0)
            done += len(new_rows)
            plan += max(sweep.runs - sweep.first_look, 0)
            spent += sum(cost[sweep.first_look :][: sweep.runs - sweep.first_look])
            budget = int(flag_value(sweep.command, "--total-timesteps") or 0)  # steps a run
            shares = [min(s / budget, 1.0) for s in begun_steps(sweep, rows)] if budget else []
            begun += shares
            unstarted = max(sweep.runs - max(len(rows), sweep.first_look), 0)
            left += per_run * max(unstarted - sum(shares), 0.0)
        wall, cpus = clocks.get(item.id, (0.0, []))
        share = f"{len(begun)} ({sum(begun) / len(begun):.0%} of their steps)" if begun else "-"
        lines.append(f"| {item.id}: {item.title} | {done} of {plan} | {spent:.1f} | {left:.1f} "
                     f"| {wall:.1f} | {'; '.join(cpus) or '-'} | {share} |")  # fmt: skip
        total_done, total_plan = total_done + done, total_plan + plan
        total_spent, total_left = total_spent + spent, total_left + left
        total_begun += len(begun)
    lines.append(
        f"| {ALL} | **{total_done} of {total_plan}** | **{total_spent:.1f}** | "
        f"**{total_left:.1f}** | **{clocks.get(ALL, (0.0,))[0]:.1f}** | | **{total_begun}** |"
    )
    return "\n".join(lines) + "\n", total_done >= total_plan


def repeat_report(items: list[Item], plan: Path) -> str:
    """The repeat items' verdicts: run 0 again against the committed run 0."""
    data = read_toml(plan)
    report = []
    for entry in data.get("item", []):
        if entry["kind"] != "repeat":
            continue
        again, before = read_rows(Path(entry["out"])), read_rows(Path(entry["source"]))
        if not again or len(again) <= (index := int(entry.get("run", 0))):
            report.append(f"- {entry['id']}: not run yet")
            continue
        a, b = float(again[index]["score"]), float(before[index]["score"])
        same = "identical" if a == b else f"differs by {a - b:+.4f}"
        if "agree_within" in entry:  # the stated criterion for "the code still learns the same"
            agree = abs(a - b) <= float(entry["agree_within"])
            same += f" ({'agrees' if agree else 'DISAGREES'}: within {entry['agree_within']})"
        report.append(f"- {entry['id']}: run {index} again {a:.4f}, committed {b:.4f}: {same}")
    return "\n".join(report) + "\n" if report else ""


def write_progress(items: list[Item], plan: Path) -> bool:
    table, finished = progress(items, plan.parent / "SWEEPS.tsv")
    shown = plan.relative_to(ROOT) if plan.is_relative_to(ROOT) else plan
    text = f"# Campaign progress ({plan.name})\n\nWritten by `python -m a3c_tools.campaign "
    text += f"{shown.as_posix()}` after each sweep.\n\n{table}"
    repeats = repeat_report(items, plan)
    if repeats:
        text += f"\nRepeated runs (run 0 of a committed line, again):\n\n{repeats}"
    (plan.parent / "PROGRESS.md").write_text(text)
    return finished


def ran_on(command: list[str]) -> str:
    """SWEEPS.tsv's cpu column: the CPU, or for a batched sweep its device too."""
    if "--backend" not in command or flag_value(command, "--backend") != "batched":
        return cpu_model()
    device = flag_value(command, "--device") or "cpu"
    if device == "cuda":
        import torch

        device = f"cuda {torch.cuda.get_device_name()}"
    return f"batched on {device}; {cpu_model()}"


def native_bf16() -> bool:
    """Whether this CPU computes bf16 natively, so that --precision auto gives bf16 at K > 1
    (a3c_runtime.flags.native_bf16, imported only when asked: it imports torch)."""
    from a3c_runtime.flags import native_bf16 as native

    return native()


def cpu_model() -> str:
    """The CPU's model name (as lscpu prints it, from /proc/cpuinfo), for the record of where
    each run ran, and "native bf16" where it has it: two VMs both called "AMD EPYC", one with
    and one without, run `--precision auto` in different precisions at K > 1."""
    name = platform.processor() or "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                name = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return f"{name}, native bf16" if native_bf16() else name


def log_sweep(plan: Path, item: Item, sweep: Sweep, before: int, started: float) -> None:
    """Write to SWEEPS.tsv beside the plan what one sweep invocation did so far: when, on which
    CPU (and how many cores), and the runs its folder held before and now. Its row (the same
    item, folder and start) is replaced if there, else added."""
    path = plan.parent / "SWEEPS.tsv"
    stamp = "%Y-%m-%d %H:%M:%S"
    row = [item.id, str(sweep.out), time.strftime(stamp, time.gmtime(started)),
           time.strftime(stamp, time.gmtime()), f"{time.time() - started:.0f}", str(before),
           str(len(read_rows(sweep.out))), ran_on(sweep.command), str(cpu_count())]  # fmt: skip
    lines = path.read_text().splitlines(keepends=True) if path.is_file() else []
    if not lines:
        lines = ["item\tout\tstarted_utc\tended_utc\twall_s\truns_before\truns_after\tcpu\tcores\n"]
    key = row[:3]
    mine = [i for i, line in enumerate(lines) if line.rstrip("\n").split("\t")[:3] == key]
    if mine:
        lines[mine[-1]] = "\t".join(row) + "\n"
    else:
        lines.append("\t".join(row) + "\n")
    partial = path.with_name(path.name + ".partial")
    partial.write_text("".join(lines))
    os.replace(partial, path)  # a killed campaign leaves the old table or the new, whole


def run_logged(plan: Path, item: Item, sweep: Sweep) -> int:
    """Run one sweep of the plan, its SWEEPS.tsv row written at its start and kept current
    every LOG_EVERY_S while it runs, so that a campaign killed outright (a session's end)
    leaves its last sweep's span in the table all the same. The sweep's exit code."""
    before = len(read_rows(sweep.out))
    started = time.time()
    log_sweep(plan, item, sweep, before, started)
    done = threading.Event()

    def keep_current() -> None:
        while not done.wait(LOG_EVERY_S):
            log_sweep(plan, item, sweep, before, started)

    logger = threading.Thread(target=keep_current, daemon=True)
    logger.start()
    try:
        code, _ = execute(sweep.command)
    finally:
        done.set()
        logger.join()
        log_sweep(plan, item, sweep, before, started)
    return code


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = Parser(
        prog="python -m a3c_tools.campaign",
        description="Run what is left of a campaign's plan, in its order (resumable).",
    )
    parser.add_argument("plan", type=Path, help="the plan (e.g. results/campaign/plan.toml)")
    parser.add_argument("--status", action="store_true", help="write and print the progress only")
    parser.add_argument("--dry-run", action="store_true", help="print the commands, run nothing")
    parser.add_argument(
        "--backend",
        choices=["local", "batched"],
        default="local",
        help="batched: the Catch sweeps of the scripts the batched backend takes as one program "
        "on --device; every other sweep on the process backend (default local: all of them)",
    )
    parser.add_argument("--device", choices=["cpu", "cuda"], default=None,
                        help="with --backend batched: cpu or cuda (default cpu)")  # fmt: skip
    parser.add_argument(
        "--batchable-last",
        action="store_true",
        help="run the Catch sweeps the batched backend takes after every other sweep (on a CPU, "
        "leaving them to a GPU while it runs what a GPU could not batch)",
    )
    options = parser.parse_args(argv)
    if options.device is not None and options.backend != "batched":
        parser.error("--device needs --backend batched")
    if options.batchable_last and options.backend == "batched":
        parser.error("--batchable-last is for the process backend; --backend batched runs them")
    options.device = options.device or "cpu"
    return options


def batchable(sweep: Sweep) -> bool:
    """Whether a sweep is a Catch sweep of a script that the batched backend takes."""
    from a3c_runtime.batchable import BATCHED_SCRIPTS

    command = sweep.command
    if command[:2] != ["-m", "a3c_tools.sweep"] or Path(command[2]).name not in BATCHED_SCRIPTS:
        return False
    own = command[: command.index("--")]
    return "--backend" not in own and flag_value(command, "--env") in (None, "Catch-v0")


def on_backend(items: list[Item], backend: str, device: str) -> list[Item]:
    """The items with their batchable sweeps on the batched backend (`--backend batched`), and
    the lines whose plan names the batched backend on `device`."""
    where = ["--backend", "batched", "--device", device]
    moved = []
    for item in items:
        sweeps = []
        for sweep in item.sweeps:
            command = sweep.command
            if flag_value(command, "--backend") == "batched":  # the plan's: on --device
                at = command.index("--device")
                command = [*command[: at + 1], device, *command[at + 2 :]]
            elif backend == "batched" and batchable(sweep):
                cut = command.index("--")
                command = [*command[:cut], *where, *command[cut:]]
            sweeps.append(dataclasses.replace(sweep, command=command))
        moved.append(dataclasses.replace(item, sweeps=sweeps))
    return moved


def passes(items: list[Item], batchable_last: bool) -> list[list[tuple[Item, list[Sweep]]]]:
    """The order the sweeps run in: the plan's, or with batchable_last two passes over the
    items, the sweeps the batched backend takes in the second."""
    if not batchable_last:
        return [[(item, list(item.sweeps)) for item in items]]
    return [
        [(item, [s for s in item.sweeps if batchable(s) == second]) for item in items]
        for second in (False, True)
    ]


def main(argv: list[str] | None = None) -> int:
    options = parse_args(sys.argv[1:] if argv is None else argv)
    options.plan = options.plan.resolve()
    os.chdir(ROOT)  # the plan's folders are the repository's
    try:
        items = on_backend(load_plan(options.plan), options.backend, options.device)
    except DataError as error:
        print(f"error: {error}", file=sys.stderr)
        return 2
    if options.device == "cuda" and not options.dry_run:
        import torch

        if not torch.cuda.is_available():
            print("error: --device cuda: torch sees no CUDA device here; use --device cpu",
                  file=sys.stderr)  # fmt: skip
            return 2
    order = passes(items, options.batchable_last)
    if options.dry_run:
        for one_pass in order:
            for item, sweeps in one_pass:
                for sweep in sweeps:
                    print(shlex.join(["python", *sweep.command]))
                if item.draw is not None and sweeps:
                    print(shlex.join(["python", *item.draw]))
        return 0
    if options.status:
        write_progress(items, options.plan)
        print((options.plan.parent / "PROGRESS.md").read_text(), end="")
        return 0
    failed = False
    ran: set[str] = set()
    for number, one_pass in enumerate(order, 1):
        for item, sweeps in one_pass:
            if item.needs_native_bf16 and not native_bf16():
                if any(len(read_rows(sweep.out)) < sweep.runs for sweep in sweeps):
                    print(f"== {item.id}: not run on this CPU: its runs take --precision auto, "
                          "which is bf16 only on a CPU with native bf16 (as its runs so far); "
                          "here they would compute in fp32", flush=True)  # fmt: skip
                continue
            for sweep in sweeps:
                before = len(read_rows(sweep.out))
                if before >= sweep.runs:
                    continue
                ran.add(item.id)
                print(f"== {item.id}: {sweep.out}: to {sweep.runs} runs", flush=True)
                code = run_logged(options.plan, item, sweep)
                write_progress(items, options.plan)
                if code in (2, 130):
                    return code
                failed |= code != 0
                if item.draw is not None:
                    failed |= execute(item.draw)[0] != 0
            # an item whose runs were all done before (or came back from another machine) is
            # drawn once a start, so that its figure's results.csv is never left behind its runs
            if (number == len(order) and item.draw is not None and item.id not in ran
                    and any(read_rows(s.out) for s in item.sweeps)):  # fmt: skip
                failed |= execute(item.draw)[0] != 0
    finished = write_progress(items, options.plan)
    print((options.plan.parent / "PROGRESS.md").read_text(), end="")
    return 1 if failed else 0 if finished else 1


if __name__ == "__main__":
    run_main(main)
