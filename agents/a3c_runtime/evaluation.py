"""The thesis's evaluation protocol (--eval-episodes episodes sampling actions from pi, every
--eval-interval global steps), played by an evaluator process beside the workers, and
--evaluate: a checkpoint's network playing episodes, in a window with --render human."""

from __future__ import annotations

import contextlib
import dataclasses
import os
import pickle
import queue
import signal
import time
import warnings
from collections.abc import Callable, Iterator
from typing import Any

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn

from .checkpoints import Checkpoint, load_checkpoint, load_network
from .flags import EVAL_EPISODES, UsageError, probe_env, resolve_precision
from .hogwild import Shared, process_seed, seed_everything
from .resume import flag, show

HUMAN_EVAL_EPISODES = 5  # --evaluate --render human: a handful to watch, not the protocol's 50


class EvaluationInterrupted(Exception):
    """Ctrl-C or SIGTERM arrived while evaluation episodes were being played."""


def play_episodes(
    model: nn.Module,
    envs: list[gym.Env],
    seeds: list[int] | None = None,
    should_stop: Callable[[], bool] = lambda: False,
    greedy: bool = False,
    generator: torch.Generator | None = None,
    on_end: Callable[[int, float], None] | None = None,
) -> np.ndarray:
    """Play one episode in each env in lock-step with one batched forward per step, sampling
    actions from pi with `generator` (greedy: argmax pi, the first of tied actions); returns
    the raw game scores, and hands each to on_end(env index, score) as its episode ends. A
    recurrent network (initial_state) carries a state row per running episode. Raises
    EvaluationInterrupted once should_stop() is true."""
    observations = [env.reset(seed=None if seeds is None else seeds[i])[0] for i, env in
                    enumerate(envs)]  # fmt: skip
    scores = np.zeros(len(envs))
    running = list(range(len(envs)))
    recurrent = hasattr(model, "initial_state")
    device = next((p.device for p in model.parameters()), torch.device("cpu"))
    state = tuple(s.to(device) for s in model.initial_state(len(envs))) if recurrent else None
    with torch.inference_mode():
        while running:
            if should_stop():
                raise EvaluationInterrupted
            batch = torch.from_numpy(np.stack([observations[i] for i in running])).to(device)
            if recurrent:
                log_probs, _, state = model(batch[None], state)  # one step (T=1)
                log_probs = log_probs[0]
            else:
                log_probs, _ = model(batch)
            log_probs = log_probs.cpu()  # (a network on a GPU: the batched backend's)
            if greedy:
                chosen = log_probs.argmax(1).tolist()
            else:
                chosen = torch.multinomial(log_probs.exp(), 1, generator=generator)
                chosen = chosen.squeeze(1).tolist()
            still_running = []
            for i, action in zip(running, chosen, strict=True):
                observations[i], _, terminated, truncated, info = envs[i].step(action)
                if terminated or truncated:
                    scores[i] = float(info["episode"]["r"])
                    if on_end is not None:
                        on_end(i, float(scores[i]))
                else:
                    still_running.append(i)
            if recurrent:  # keep the state rows of the episodes still running
                state = tuple(s[[running.index(i) for i in still_running]] for s in state)
            running = still_running
    return scores


def make_eval_envs(
    agent: Any, args: Any, video_dir: str | None, prefix: str = "rl-video", every: bool = False
) -> list[gym.Env]:
    """--eval-episodes envs; with a video_dir the first records every episode it plays (every:
    each env records its own, as `prefix-<n>`; drawing the screen changes no episode)."""
    envs = []
    for i in range(args.eval_episodes):
        if video_dir and (i == 0 or every):
            env = agent.make_env(args.env, render_mode="rgb_array")
            with warnings.catch_warnings():  # one folder for many recorders, each its own name
                warnings.filterwarnings("ignore", message=".*Overwriting existing videos")
                env = gym.wrappers.RecordVideo(
                    env, video_dir, episode_trigger=lambda _: True,
                    name_prefix=f"{prefix}-{i + 1}" if every else prefix,
                )  # fmt: skip
        else:
            env = agent.make_env(args.env)
        envs.append(env)
    return envs


EVALUATION_STREAM = 7_307  # keys the evaluation episodes' random numbers apart from the workers'


def evaluate_network(
    model: nn.Module,
    envs: list[gym.Env],
    global_step: int,
    args: Any,
    should_stop: Callable[[], bool] = lambda: False,
    on_end: Callable[[int, float], None] | None = None,
) -> dict:
    """One evaluation of the thesis protocol: an episode per env, sampling from pi (argmax pi
    with --eval-greedy); on_end hears each episode's score as it ends (play_episodes). Its
    random numbers (the episodes' seeds, the sampled actions) come from --seed and the step, so
    the evaluation of a step is the same in a resumed run and in --evaluate of the step's
    checkpoint."""
    if hasattr(model, "set_progress"):  # e.g. GLPQ's temperature schedule
        model.set_progress(global_step / args.total_timesteps)
    start = time.time()
    seeds, generator = evaluation_randomness(args.seed, global_step, len(envs))
    scores = play_episodes(model, envs, seeds, should_stop, args.eval_greedy, generator, on_end)
    return {"global_step": global_step, "scores": scores.tolist(), "seconds": time.time() - start}


def evaluation_randomness(seed: int, global_step: int, episodes: int) -> tuple[list[int], Any]:
    """The episodes' seeds and the action sampler's generator of the evaluation at a step."""
    rng = np.random.default_rng([seed, EVALUATION_STREAM, global_step])
    seeds = rng.integers(2**31, size=episodes).tolist()
    return seeds, torch.Generator().manual_seed(int(rng.integers(2**62)))


def evaluator(
    agent: Any, shared: Shared, args: Any, requests: Any, run_dir: str, evaluations: Any
) -> None:
    """The evaluator process: evaluates each (step, theta) that the main process hands it
    (`requests`: the copies the workers took at the evaluation marks, step 0's first), in
    order, until None ends the run's requests. SIGTERM drops the evaluation it plays."""
    seed_everything(process_seed(args.seed, args.num_workers))
    envs = make_eval_envs(
        agent, args, os.path.join(run_dir, "videos") if args.capture_video else None
    )
    model = agent.build_network(envs[0].action_space.n, args)

    def signalled() -> bool:  # a running evaluation completes when the run ends, unless...
        return shared.signalled or shared.orphaned()

    try:
        while not signalled():
            try:
                request = requests.get(timeout=0.05)
            except queue.Empty:
                continue
            if request is None:  # the run's last request was handed over
                break
            step, state = pickle.loads(request)
            model.load_state_dict(state)
            evaluations.put(evaluate_network(model, envs, step, args, signalled))
    except EvaluationInterrupted:
        pass
    for env in envs:
        env.close()


# what --evaluate takes from the command line; every other flag is the checkpoint's
EVALUATE_FLAGS = ("seed", "eval_episodes", "eval_greedy", "render", "capture_video", "evaluate")


def check_evaluate_flags(trained: Any, args: Any, given: set[str]) -> None:
    """UsageError for a flag given with --evaluate (`given`: the Args fields named on the
    command line) outside EVALUATE_FLAGS whose value differs from the checkpoint's."""
    for name in sorted(given - set(EVALUATE_FLAGS)):
        new, old = getattr(args, name), getattr(trained, name)
        if name == "precision":  # --precision auto: what it resolves to for the run
            new = resolve_precision(new, getattr(trained, "envs_per_worker", 1))
        if new != old:
            valid = ", ".join(flag(n) for n in EVALUATE_FLAGS[:-1])
            raise UsageError(
                f"{flag(name)} {show(new)} differs from the checkpoint's {show(old)}: --evaluate "
                f"plays the checkpoint's env and network with its flags; only {valid} apply"
            )


def evaluation_protocol(trained: Any, args: Any, given: set[str]) -> Any:
    """--evaluate's protocol: the run's own evaluations' (its --seed, --eval-episodes and
    --eval-greedy, from the checkpoint), each of them given on the command line (`given`; an
    --eval-episodes that is not None) replacing the run's; --render human plays a handful to
    watch unless --eval-episodes is given."""
    protocol = dataclasses.replace(trained)
    for name in ("seed", "eval_greedy"):
        if name in given:
            setattr(protocol, name, getattr(args, name))
    if args.eval_episodes is not None:
        protocol.eval_episodes = args.eval_episodes
    elif args.render == "human":
        protocol.eval_episodes = HUMAN_EVAL_EPISODES
    elif protocol.eval_episodes is None:
        protocol.eval_episodes = EVAL_EPISODES
    if protocol.eval_episodes < 1:
        raise UsageError(f"--eval-episodes must be >= 1 (got {protocol.eval_episodes})")
    return protocol


@contextlib.contextmanager
def signals_stop_episodes() -> Iterator[list[str]]:
    """While --evaluate plays, SIGINT and SIGTERM end its episodes at their next step instead of
    ending the process, so that the episodes that ended are still reported; the first signal's
    name lands in the list yielded."""
    caught: list[str] = []

    def on_signal(signum: int, _frame: Any) -> None:
        if not caught:
            caught.append(signal.Signals(signum).name)

    previous = {s: signal.signal(s, on_signal) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield caught
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)


def evaluate(agent: Any, args: Any, given: set[str] = frozenset()) -> np.ndarray:
    """--evaluate: play episodes with a checkpoint's network, print each score as its episode
    ends and then the mean; returns the scores of the episodes that ended, in episode order.
    With the run's protocol (evaluation_protocol) and the checkpoint's step, the episodes and
    the actions are those of the run's evaluation at that step (evaluate_network): the final
    checkpoint's score is the run's final evaluation. --render human plays one episode at a
    time in a window (the same episodes' seeds, other action samples). Ctrl-C or SIGTERM stops
    the episodes; those that ended are reported, and the command ends normally. A flag named on
    the command line (`given`) that the checkpoint's flags contradict is refused
    (check_evaluate_flags)."""
    with signals_stop_episodes() as caught:  # (from the start: a Ctrl-C while loading stops it too)
        return evaluate_until_stopped(agent, args, given, caught)


def evaluate_until_stopped(agent: Any, args: Any, given: set[str], caught: list[str]) -> np.ndarray:
    """evaluate(), its episodes stopped once `caught` names a signal."""
    # one thread, as the run's evaluations play (train sets it): on a CPU that others share, a
    # second thread's waits made the Breakout checkpoint's 10 episodes take 124 s, not 21
    torch.set_num_threads(1)
    checkpoint = load_checkpoint(args.evaluate, agent, "--evaluate")
    trained = checkpoint.flags
    check_evaluate_flags(trained, args, given)
    protocol = evaluation_protocol(trained, args, given)
    window = args.render == "human" and not args.capture_video  # (a video draws no window)
    if window:
        from catch_env.rendering import NoDisplayError, check_display

        try:
            check_display()  # rather than episodes played in no window
        except NoDisplayError as e:
            raise UsageError(str(e)) from None
        except ImportError:
            pass  # the env names what it needs
    seed_everything(protocol.seed)
    num_actions = probe_env(agent.make_env, checkpoint.env)
    model = agent.build_network(num_actions, trained)  # as the run's evaluator builds it
    load_network(model, checkpoint)
    video_dir = str(checkpoint.run_folder / "videos-evaluate") if args.capture_video else None
    total, head = protocol.eval_episodes, f"{checkpoint.env}, step {checkpoint.global_step:,}"
    policy = "argmax pi" if protocol.eval_greedy else "sampling from pi"
    # the episodes of a batch end far apart on Atari: each score is shown as it comes
    how = "one at a time in a window" if window else "at once, each score as its episode ends"
    print(f"{head}: {total} episodes ({policy}), {how}", flush=True)
    ended: dict[int, float] = {}

    def on_end(index: int, score: float) -> None:
        ended[index] = score
        print(f"episode {index + 1}: score {score:g}", flush=True)

    stopping = lambda: bool(caught)  # noqa: E731
    try:
        if window:
            watched_episodes(agent, model, checkpoint, protocol, stopping, on_end)
        else:
            envs = make_eval_envs(agent, protocol, video_dir, "episode", every=True)
            try:
                evaluate_network(model, envs, checkpoint.global_step, protocol, stopping, on_end)
            finally:
                for env in envs:
                    env.close()
    except EvaluationInterrupted:
        pass
    scores = np.asarray([ended[i] for i in sorted(ended)])
    over = f"{len(scores)} episodes"
    if len(scores) < total:  # only a signal ends the episodes early
        print(f"stopped by {caught[0]} after {len(scores)} of {total} episodes", flush=True)
        over = f"the {len(scores)} of {total} episodes that ended"
    if len(scores):
        print(f"{head}: mean score {scores.mean():.3f} +- {scores.std():.3f} over {over}",
              flush=True)  # fmt: skip
    return scores


def watched_episodes(
    agent: Any,
    model: nn.Module,
    checkpoint: Checkpoint,
    protocol: Any,
    should_stop: Callable[[], bool],
    on_end: Callable[[int, float], None],
) -> None:
    """--render human: the protocol's episodes one at a time in a window, each score handed to
    on_end(episode index, score); raises EvaluationInterrupted once should_stop() is true."""
    if hasattr(model, "set_progress"):  # e.g. GLPQ's temperature schedule
        model.set_progress(checkpoint.global_step / protocol.total_timesteps)
    seeds, generator = evaluation_randomness(
        protocol.seed, checkpoint.global_step, protocol.eval_episodes
    )
    env = agent.make_env(checkpoint.env, render_mode="human")
    try:
        for episode, seed in enumerate(seeds):
            play = play_episodes(model, [env], [seed], should_stop, protocol.eval_greedy,
                                 generator)  # fmt: skip
            on_end(episode, float(play[0]))
    finally:
        env.close()
