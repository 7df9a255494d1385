"""--resume continues the same experiment: every flag comes from the checkpoint. A flag given
with --resume that does not change the experiment (RESUMABLE: how long it runs, how many
workers, how often it evaluates, logs and checkpoints, videos) applies and is announced; any
other that differs from the run's is refused. Where the run writes and where its data goes
(COMMAND_LINE_ONLY: the run folder, W&B tracking) are this command's alone, never the
checkpoint's: a checkpoint is someone else's data."""

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
)
# where a run's data goes (Weights & Biases): a checkpoint handed on would otherwise send this
# machine's run to its writer's entity; only the command line sets it
ELSEWHERE = ("track", "wandb_entity", "wandb_project_name")
# about this command, not the experiment: where it writes (by default the checkpoint's folder)
# and where its data goes
COMMAND_LINE_ONLY = ("resume", "evaluate", "render", "run_dir", "runs_root", *ELSEWHERE)


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
    the command line, and the COMMAND_LINE_ONLY flags of the command line alone. Prints a line
    for each flag that changes, for each flag the checkpoint predates (it takes the value
    agent.trained_args gives it), for a --time-limit the run keeps and for W&B tracking of the
    run that the command line does not give again (tracking_note); UsageError for a given flag
    that would change the experiment."""
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
    note = tracking_note(values, args, given)
    if note is not None:
        print(note, flush=True)
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


def destination(entity: str | None, project: str) -> str:
    """Where a tracked run logs, in words (the names quoted: they may come from a file)."""
    shown = "yours (the default)" if entity is None else repr(entity)
    return f"W&B entity {shown}, project {project!r}"


def tracking_note(run: dict, args: Any, given: set[str]) -> str | None:
    """The line for a resume of a run that was tracked, where --resume once took the tracking,
    its entity or its project from the checkpoint and now takes them from the command line
    only (run: the run's flags; args, given: the command line's): where this part's data goes.
    None when the run was not tracked, or the command line says the same or says it all."""
    if not run["track"]:
        return None  # the run sent nothing anywhere
    if not args.track:
        if "track" in given:  # --no-track: asked for
            return None
        now = "is not tracked (--track, with --wandb-entity and --wandb-project-name, tracks it)"
    elif all(name in given or run[name] == getattr(args, name) for name in ELSEWHERE):
        return None
    else:
        now = f"logs to {destination(args.wandb_entity, args.wandb_project_name)}"
    return (
        "note: the checkpoint's run was tracked "
        f"({destination(run['wandb_entity'], run['wandb_project_name'])}); --resume takes where a "
        f"run's data goes from the command line only: this part {now}"
    )


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
