"""A3C's structure and the command line: `train` (one shared network and optimizer, N
actor-learner processes, an evaluator) and `run` (train, or --evaluate a checkpoint)."""

from __future__ import annotations

import contextlib
import os
import pickle
import shlex
import sys
import time
import traceback
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import torch

from .checkpoints import (
    Checkpoint,
    WriteFailed,
    check_checkpoint_path,
    checkpoint_step,
    load_checkpoint,
    restore,
    save_checkpoint,
)
from .evaluation import (
    EvaluationInterrupted,
    evaluate,
    evaluate_network,
    evaluator,
    make_eval_envs,
)
from .flags import UsageError, probe_env, refuse_tf32, resolve_defaults
from .hogwild import Shared, seed_everything
from .resume import given_flags, resumed_args
from .run_folder import RunFolder, resume_folder, run_folder_path
from .run_log import RunLog, last_evaluation, logged_steps, summarize
from .snapshots import CHECKPOINT, EVALUATE, copy_of
from .supervision import FORK, RunFailed, Supervisor

LATE = 2  # evaluations pending beyond which the console says the evaluator is behind


def train(
    agent: Any, args: Any, checkpoint: Checkpoint | None = None, folder: RunFolder | None = None
) -> dict:
    """A3C (thesis section 2.2.3, Algorithm 1): the global network theta and its optimizer
    statistics live in shared memory; N actor-learner processes each run `agent.worker`, which
    syncs theta, acts and updates theta without locks (Hogwild); an evaluator process plays the
    thesis's evaluation protocol beside them. Returns the run's summary. Raises UsageError for a
    bad checkpoint, flag, env or run folder before anything is created; RunFailed when a process
    dies and WriteFailed when a file cannot be written, each with `run_dir` set. `run` passes a
    resumed run's checkpoint and its folder, locked before the checkpoint was read."""
    torch.set_num_threads(1)  # before any torch op, so that forking the workers is safe
    refuse_tf32(args.precision)
    if args.resume and folder is None:
        check_checkpoint_path(args.resume, "--resume")  # before the folder is touched
        folder = resume_folder(args)
    if args.resume and checkpoint is None:
        checkpoint = load_checkpoint(args.resume, agent, "--resume")
    if checkpoint is not None and folder is not None and is_finished(checkpoint, args, folder.path):
        folder.close()  # (idempotent: run() closes the folder it passed too)
        return finished_summary(checkpoint, args, folder.path)
    seed_everything(args.seed)
    num_actions = probe_env(agent.make_env, args.env)
    # the network is built before the run folder: its constructor rejects bad flags
    network = agent.build_network(num_actions, args)
    if checkpoint is None and agent.initialize is not None:
        agent.initialize(network, args)
    shared = Shared(network, args, FORK)
    if checkpoint is not None:
        restore(shared, checkpoint, args, args.resume, agent)
    start_step = shared.global_step()
    # the evaluations not taken yet: a fresh run's step 0; a resumed run's, from its checkpoint
    pending = list(checkpoint.pending_evaluations) if checkpoint else []
    if checkpoint is None:
        pending.append((0, copy_of(shared.model.state_dict())))
    # the marks of the evaluations and checkpoints, and the workers' saved states, before the
    # workers fork (a3c_runtime.snapshots)
    shared.marks.start(start_step, args, checkpoint.workers if checkpoint else None)
    if folder is None:  # a new run's folder: created now that its flags have been checked
        folder = RunFolder(run_folder_path(args, resuming=False), new_run=True)  # locked
    run_dir = folder.path
    # (an evaluation the killed run logged after its checkpoint was written is not taken again)
    logged = logged_steps(run_dir / "evaluations.csv", start_step)
    pending = [request for request in pending if request[0] not in logged]
    evaluations, requests = FORK.SimpleQueue(), FORK.Queue()
    for request in pending:
        requests.put(pickle.dumps(request))  # by value (see a3c_runtime.snapshots.send)
    processes = {f"worker {i}": (agent.worker, i, shared, args) for i in range(args.num_workers)}
    processes["evaluator"] = (evaluator, agent, shared, args, requests, str(run_dir), evaluations)
    supervisor = Supervisor(shared, processes)
    log = None
    try:  # (the first lines too: a closed stdout stops the processes like any failure)
        if checkpoint is not None:
            print(f"resuming run {run_dir.name} at step {start_step:,} -> {run_dir}", flush=True)
        else:
            print(f"run {run_dir.name} -> {run_dir}", flush=True)
        print(f"pids: {supervisor.pids()}", flush=True)
        # after the fork: the TensorBoard writer's thread must not be forked
        wall_time = checkpoint.wall_time if checkpoint else 0.0
        log = RunLog(run_dir, args, wall_time, resumed_step=start_step)
        outcome, sps = watch(
            agent, supervisor, shared, args, log, (requests, evaluations, pending), run_dir,
            start_step,
        )  # fmt: skip
        log.close()
    except BaseException as e:
        supervisor.stop(finished=False)  # (stopped already, unless RunLog itself failed)
        if log is not None:
            log.close(quietly=True)
        if isinstance(e, Exception):
            e.run_dir = run_dir  # for the closing line
        raise
    finally:
        supervisor.restore_signal_handlers()
        folder.close()
        # the evaluator has ended: requests it never read (a run stopped while it was behind)
        # must not hold this process at its exit, its queue's thread waiting for a reader
        requests.cancel_join_thread()
    return summarize(outcome, sps, shared.global_step(), log, run_dir)


def watch(
    agent: Any,
    supervisor: Supervisor,
    shared: Shared,
    args: Any,
    log: RunLog,
    evaluation_queues: tuple[Any, Any, list],
    run_dir: Path,
    start_step: int,
) -> tuple[str, float]:
    """The main process while the workers train: hand the evaluator the copies of theta the
    workers took at the evaluation marks and log its results, write the checkpoints they took
    at the checkpoint marks, log progress, and stop at T_max, the time limit, a signal or a
    failure; then the final checkpoint and the final evaluation, of the network after the last
    update. Returns (outcome, steps/s)."""
    requests, evaluations, pending = evaluation_queues
    checkpoint_path = run_dir / "checkpoint.pt"
    outcome = None
    steady_start = None  # (time, step) once every worker has finished a rollout, for the SPS
    final_states: dict[int, list] = {}  # each worker's state as its loop ended
    behind = [False]  # the evaluator is more than LATE evaluations behind (announced once)

    def take_results() -> None:
        """Log the evaluator's results so far; then say, once, if it is behind."""
        while not evaluations.empty():
            result = evaluations.get()
            log.evaluation(result)
            pending[:] = [p for p in pending if p[0] != result["global_step"]]
        if len(pending) > LATE and not behind[0]:
            waiting = f"the one of step {pending[0][0]:,} waits"
            print(f"note: the evaluator is {len(pending)} evaluations behind the training "
                  f"({waiting}); each is taken all the same", flush=True)  # fmt: skip
        behind[0] = len(pending) > LATE

    def drain(every: bool = False) -> None:
        """The workers' snapshots and the evaluator's results so far, in order (every: the
        workers have ended, see StepMarks.receive)."""
        while (event := shared.marks.receive(every)) is not None:
            if event[0] == EVALUATE:
                pending.append(event[1:])
                requests.put(pickle.dumps(event[1:]))
                take_results()  # at each request: one drain may write checkpoints for seconds
            elif event[0] == CHECKPOINT:
                step, model, optimizer, workers = event[1:]
                snapshot = {"model": model, "optimizer": optimizer, "global_step": step,
                            "workers": workers, "pending_evaluations": list(pending)}  # fmt: skip
                save_checkpoint(checkpoint_path, shared, args, log.wall_time(), agent.script,
                                snapshot)  # fmt: skip
            else:  # FINAL
                final_states[event[1]] = event[2]
        take_results()

    loop_ended = False
    try:
        while outcome is None and not supervisor.failures:
            time.sleep(0.1)
            # exit codes before the step: a worker that ended normally saw step >= T_max
            codes = supervisor.exit_codes()
            now, global_step = time.time(), shared.global_step()
            if steady_start is None and bool((shared.steps > 0).all()):
                steady_start = (now, global_step)
            supervisor.read_errors()
            drain()
            if supervisor.signal_name is not None:  # (a signal to the whole group ends the
                outcome = f"stopped by {supervisor.signal_name}"  # workers early: not a failure)
                break
            supervisor.check_exits(codes, global_step, args.total_timesteps)
            if not supervisor.failures and supervisor.workers_done(codes):
                outcome = "done"
            elif args.time_limit is not None and now - log.start >= args.time_limit:
                outcome = "time limit"
            if log.progress_due():
                log.progress(global_step, shared.stats.sum(0))
        loop_ended = True
    finally:  # a failed write ends the loop too: the processes stop, the evaluator at once
        finished = loop_ended and outcome in ("done", "time limit") and not supervisor.failures
        # the workers end their loops, their last snapshots drained; then a finished run's
        # evaluator takes every evaluation left (None: no more), any other's stops at once
        supervisor.stop_workers(drain)
        requests.put(None)
        supervisor.stop(finished, drain)
    end_time, global_step = time.time(), shared.global_step()
    drain(every=True)
    shared.marks.close()
    if supervisor.failures:
        raise RunFailed("\n".join(supervisor.failures))
    if supervisor.signal_name is not None and finished:
        outcome = f"stopped by {supervisor.signal_name} in the final evaluation"
    snapshot = {"workers": final_states, "pending_evaluations": list(pending)}
    save_checkpoint(checkpoint_path, shared, args, log.wall_time(), agent.script, snapshot)
    if outcome in ("done", "time limit"):
        video_dir = str(run_dir / "videos") if args.capture_video else None
        envs = make_eval_envs(agent, args, video_dir, prefix="final")
        try:
            stopping = lambda: shared.signalled  # noqa: E731
            log.evaluation(evaluate_network(shared.model, envs, global_step, args, stopping))
        except EvaluationInterrupted:
            outcome = f"stopped by {supervisor.signal_name} in the final evaluation"
        for env in envs:
            env.close()
    start_time, start_of_sps = steady_start or (log.start, start_step)
    return outcome, (global_step - start_of_sps) / max(end_time - start_time, 1e-9)


def is_finished(checkpoint: Checkpoint, args: Any, run_dir: Path) -> bool:
    """Whether the run a checkpoint continues into run_dir has nothing left to do: its step at
    T_max or past it, and its final evaluation in run_dir's evaluations.csv."""
    step = checkpoint.global_step
    return step >= args.total_timesteps and step in logged_steps(run_dir / "evaluations.csv", step)


def finished_summary(checkpoint: Checkpoint, args: Any, run_dir: Path) -> dict:
    """A finished run resumed: nothing is started or written; one line says so."""
    step, last = checkpoint.global_step, last_evaluation(run_dir / "evaluations.csv")
    print(
        f"run {run_dir.name} is finished: step {step:,} of --total-timesteps "
        f"{args.total_timesteps:,}, final eval {last['mean_return']:.3f} at step "
        f"{last['global_step']:,}; nothing to do (a larger --total-timesteps continues it) | "
        f"{run_dir}",
        flush=True,
    )
    return {
        "outcome": "finished already", "run_dir": str(run_dir), "global_step": step,
        "final_eval": last["mean_return"], "final_eval_step": last["global_step"],
        "wall_time_s": checkpoint.wall_time, "part_time_s": 0.0, "eval_time_s": 0.0,
        "sps": 0.0,
    }  # fmt: skip


@contextlib.contextmanager
def closed_stdout_ends_quietly() -> Iterator[None]:
    """A reader that closes stdout early (`--help | head -1`) ends the command with exit code 1
    and no BrokenPipeError traceback (Python's recipe, in the signal module's documentation)."""
    try:
        try:
            yield
        finally:
            sys.stdout.flush()  # here, where a closed pipe can still be caught
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())  # so that the flush at exit cannot fail again
        sys.exit(1)


def run(agent: Any) -> int:
    """The command line: train, or --evaluate a checkpoint. Exit codes: 0 ok (a run stopped by
    a signal included), 1 a process died or a file could not be written (or stdout was closed),
    2 bad usage (a one-line message, nothing created). A run that ends before T_max ends with a
    line naming the checkpoint that survives and the command that resumes it."""
    with closed_stdout_ends_quietly():
        return command_line(agent)


def command_line(agent: Any) -> int:
    """run(), stdout open."""
    import tyro

    args = tyro.cli(agent.Args)
    import catch_env  # noqa: F401  (registers Catch-v0 and the ALE ids)

    try:
        if args.evaluate:
            evaluate(agent, args, given_flags(sys.argv[1:], agent.Args))
            return 0
        if args.resume:  # the same experiment, its folder locked before the checkpoint is read
            check_checkpoint_path(args.resume, "--resume")  # before the folder is touched
            folder = resume_folder(args)
            try:
                checkpoint = load_checkpoint(args.resume, agent, "--resume")
                given = given_flags(sys.argv[1:], agent.Args)
                args = resumed_args(agent, checkpoint, args, given)
                summary = train(agent, resolve_defaults(args), checkpoint, folder)
            finally:
                folder.close()
        else:
            summary = train(agent, resolve_defaults(args))
    except UsageError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except (RunFailed, WriteFailed) as e:
        print(f"error: {e}", file=sys.stderr)
        print(resume_hint(agent, e.run_dir), file=sys.stderr, flush=True)
        return 1
    except BrokenPipeError as e:  # stdout closed mid-run: the run stopped; say how to go on
        if hasattr(e, "run_dir"):
            print(resume_hint(agent, e.run_dir), file=sys.stderr, flush=True)
        raise
    except Exception as e:  # a bug: its traceback, then how to go on
        if hasattr(e, "run_dir"):
            traceback.print_exc()
            print(resume_hint(agent, e.run_dir), file=sys.stderr, flush=True)
            return 1
        raise
    if summary["outcome"] not in ("done", "finished already"):
        print(resume_hint(agent, Path(summary["run_dir"])), flush=True)
    return 0


def resume_hint(agent: Any, run_dir: Path) -> str:
    """The closing line of a run that ended before T_max: its surviving checkpoint, that
    checkpoint's step, and the command that resumes it (or, with none that verifies and loads,
    starts it again)."""
    named = os.path.basename(sys.argv[0]) == os.path.basename(agent.script)
    script = sys.argv[0] if named else os.path.join("agents", agent.script)
    path = run_dir / "checkpoint.pt"
    step = checkpoint_step(path, agent) if path.exists() else None
    relative = os.path.relpath(path)
    shown = str(path) if relative.startswith("..") else relative
    if step is None:
        again = shlex.join(["python", script, *sys.argv[1:]])
        named_folder = any(a == "--run-dir" or a.startswith("--run-dir=") for a in sys.argv[1:])
        if named_folder and run_dir.exists():
            # the command names this folder: a fresh attempt must not mix with the dead one (a
            # folder removed already needs no rm, whose failure would stop the command at once)
            again = f"rm -r -- {shlex.quote(str(run_dir))} && {again}"
        if path.exists():  # changed on disk since it was written: never offered for --resume
            return f"checkpoint {shown} does not verify (corrupt); start the run again: {again}"
        if not run_dir.exists():  # removed during the run: with whatever the run wrote there
            return (
                f"the run folder {run_dir} was removed during the run, with the checkpoints and "
                f"logs written there; start the run again: {again}"
            )
        return f"no checkpoint was written in {run_dir}; start the run again: {again}"
    resume = shlex.join(["python", script, "--resume", shown])
    return f"checkpoint {shown} (step {step:,}) survives; resume: {resume}"
