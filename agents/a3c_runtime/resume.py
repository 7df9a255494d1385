"""--resume continues the same experiment: every flag comes from the checkpoint. A flag given
with --resume that does not change the experiment (RESUMABLE: how long it runs, how many
workers, how often it evaluates, logs and checkpoints, videos) applies and is announced; any
other that differs from the run's is refused."""

from __future__ import annotations

import dataclasses
from typing import Any

from .checkpoints import Checkpoint
from .flags import UsageError, resolve_precision

RESUMABLE = (
    "total_timesteps",
    "time_limit",
    "num_workers",
    "eval_interval",
    "eval_episodes",
    "checkpoint_interval",
    "log_interval",
    "capture_video",
    "track",
    "wandb_project_name",
    "wandb_entity",
)
# about this command, not the experiment: where it writes (by default the checkpoint's folder)
COMMAND_LINE_ONLY = ("resume", "evaluate", "render", "run_dir", "runs_root")


def flag(name: str) -> str:
    return "--" + name.replace("_", "-")


def given_flags(argv: list[str], args_type: type) -> set[str]:
    """The Args fields named on the command line (`--name value`, `--name=value`, and a bool's
    `--no-name`)."""
    fields = {f.name for f in dataclasses.fields(args_type)}
    given = set()
    for token in argv:
        if not token.startswith("--"):
            continue
        name = token[2:].split("=", 1)[0].replace("-", "_")
        if name not in fields and name.startswith("no_"):
            name = name[3:]
        if name in fields:
            given.add(name)
    return given


def show(value: Any) -> str:
    return f"{value:,}" if isinstance(value, int) and not isinstance(value, bool) else str(value)


def resumed_args(agent: Any, checkpoint: Checkpoint, args: Any, given: set[str]) -> Any:
    """The Args of the run being resumed: the checkpoint's, with the RESUMABLE flags given on
    the command line. Prints a line for each flag that changes, for each flag the checkpoint
    predates (it takes the value agent.trained_args gives it) and for a --time-limit the run
    keeps; UsageError for a given flag that would change the experiment."""
    trained = agent.trained_args(checkpoint)
    values = {}
    for name in (f.name for f in dataclasses.fields(agent.Args)):
        # a flag newer than the checkpoint: the value the run had (trained_args), else its default
        values[name] = trained[name] if name in trained else getattr(agent.Args(), name)
        if name not in checkpoint.args and name not in COMMAND_LINE_ONLY:
            print(
                f"note: the checkpoint predates {flag(name)}; the run goes on with "
                f"{show(values[name])}",
                flush=True,
            )
    for name in sorted(given - set(COMMAND_LINE_ONLY)):
        new, old = getattr(args, name), values[name]
        if name == "precision":  # --precision auto: what it resolves to here
            new = resolve_precision(new, values["envs_per_worker"])
        if new == old:
            continue
        if name not in RESUMABLE:
            raise UsageError(
                f"{flag(name)} {show(new)} differs from the run's {show(old)}: a resumed run keeps "
                f"its flags; only {', '.join(flag(n) for n in RESUMABLE)} may change"
            )
        print(f"{name} {show(old)} -> {show(new)}", flush=True)
        values[name] = new
    if values["time_limit"] is not None and "time_limit" not in given:  # else it is a surprise
        print(
            f"note: the run keeps its --time-limit {show(values['time_limit'])}: this part stops "
            "after that many seconds too; --time-limit SECONDS changes it, --time-limit None "
            "removes it",
            flush=True,
        )
    for name in COMMAND_LINE_ONLY:
        values[name] = getattr(args, name)
    return agent.Args(**values)


def differing_flags(
    agent: Any, checkpoint: Checkpoint, args: Any, skip: tuple[str, ...] = ()
) -> list[str]:
    """The flags (COMMAND_LINE_ONLY and skip aside) of args, defaults resolved, that differ from
    the run a checkpoint holds, each as `--name THE_RUN'S, not ARGS'`: [] when the checkpoint is
    of the run args describe (a sweep's planned run, say)."""
    trained, default = agent.trained_args(checkpoint), agent.Args()
    differ = []
    for name in (f.name for f in dataclasses.fields(agent.Args)):
        if name in COMMAND_LINE_ONLY or name in skip:
            continue
        old = trained[name] if name in trained else getattr(default, name)
        if getattr(args, name) != old:
            differ.append(f"{flag(name)} {show(old)}, not {show(getattr(args, name))}")
    return differ
