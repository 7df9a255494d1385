"""Play Catch-v0, or any game that renders RGB frames (Atari included), with the keyboard.

    python -m catch_env.play                        # Catch: arrow keys or A/D
    catch-play --env BreakoutNoFrameskip-v4         # arrows/WASD, space is FIRE
    catch-play --list-envs                          # the ids --env accepts

Esc, closing the window, Ctrl-C or SIGTERM quits and prints a summary saying which (e.g.
"quit: stopped by SIGTERM"); the exit status is 0 however the session ended, 2 for bad
flags or no display (`SDL_VIDEODRIVER=dummy` plays headless, for tests and CI). The game
advances one step per
frame at `--fps`; the default is the game's real speed (10 steps/s for Catch, 60 frames/s
for Atari). Atari games are played raw (`gym.make(id, render_mode="rgb_array")`), without
the learner's preprocessing.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.util
import itertools
import os
import signal
import sys
import threading
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from typing import Any

import gymnasium as gym
import numpy as np

from catch_env.rendering import NoDisplayError, Window, check_display
from catch_env.wrappers import ATARI_ENTRY_POINT, is_atari

BUTTONS = ("UP", "DOWN", "LEFT", "RIGHT", "FIRE")
OPPOSITE_PAIRS = (("UP", "DOWN"), ("LEFT", "RIGHT"))
# The Atari 2600 runs at 60 frames/s; an ALE step covers `frameskip` of them.
ATARI_FRAMES_PER_SECOND = 60.0
# Default window zoom aims at a window about this many pixels tall.
TARGET_WINDOW_HEIGHT = 540


class UnplayableEnvError(ValueError):
    """An env id that is unknown, or names a game that cannot be played from the keyboard."""


OnStep = Callable[[gym.Env, int, float], None]


def action_buttons(meaning: str) -> frozenset[str] | None:
    """The buttons an ALE-style action name holds down: "UPLEFTFIRE" -> {UP, LEFT, FIRE}.

    "NOOP" holds none. Names that are not a combination of UP/DOWN, LEFT/RIGHT and FIRE
    (in that order) give None, so such actions are never chosen from the keyboard.
    """
    if meaning == "NOOP":
        return frozenset()
    buttons = set()
    rest = meaning
    if rest.endswith("FIRE"):
        buttons.add("FIRE")
        rest = rest.removesuffix("FIRE")
    for vertical in ("UP", "DOWN"):
        if rest.startswith(vertical):
            buttons.add(vertical)
            rest = rest.removeprefix(vertical)
            break
    if rest in ("LEFT", "RIGHT"):
        buttons.add(rest)
        rest = ""
    return frozenset(buttons) if buttons and not rest else None


def build_key_map(meanings: Sequence[str]) -> dict[frozenset[str], int]:
    """The action to take for every set of held buttons, given the game's action names.

    Opposite directions held together cancel. Held buttons pick the action with exactly
    those buttons; when the game has none (UPLEFT in a game without diagonals, FIRE in
    Catch), they pick the action holding the most of them, preferring a move to FIRE and
    then the lowest index. Nothing held is NOOP (or action 0 for a game without NOOP).
    """
    actions = [(index, action_buttons(meaning)) for index, meaning in enumerate(meanings)]
    playable = [(index, buttons) for index, buttons in actions if buttons is not None]
    key_map = {}
    for count in range(len(BUTTONS) + 1):
        for held in itertools.combinations(BUTTONS, count):
            pressed = set(held)
            for first, second in OPPOSITE_PAIRS:
                if first in pressed and second in pressed:
                    pressed -= {first, second}
            candidates = [(index, buttons) for index, buttons in playable if buttons <= pressed]
            # Most buttons matched wins; among equals, moving beats firing (LEFT over FIRE
            # for left + space in Breakout), then the lowest index (max() keeps the first).
            best = max(
                candidates,
                key=lambda candidate: (len(candidate[1]), len(candidate[1] - {"FIRE"})),
                default=(0, None),
            )
            key_map[frozenset(held)] = best[0]
    return key_map


def _keyboard_buttons(pygame: Any) -> dict[int, str]:
    """pygame key code -> button: arrows and WASD move, space is FIRE."""
    return {
        pygame.K_UP: "UP",
        pygame.K_w: "UP",
        pygame.K_DOWN: "DOWN",
        pygame.K_s: "DOWN",
        pygame.K_LEFT: "LEFT",
        pygame.K_a: "LEFT",
        pygame.K_RIGHT: "RIGHT",
        pygame.K_d: "RIGHT",
        pygame.K_SPACE: "FIRE",
    }


def check_env_id(env_id: str) -> None:
    """Raise UnplayableEnvError, saying how to list the ids, if `env_id` is not registered."""
    is_atari("Catch-v0")  # registers the ALE ids, if ale-py is installed
    try:
        gym.spec(env_id)
    except gym.error.Error as error:
        message = f"Unknown env id {env_id!r} ({error}). List the ids with: catch-play --list-envs"
        if importlib.util.find_spec("ale_py") is None:
            message += " (Atari ids need ale-py: pip install 'catch-env[atari]')"
        raise UnplayableEnvError(message) from None


def make_play_env(env_id: str) -> gym.Env:
    """The raw game `env_id` rendering RGB frames, checked to be playable from the keyboard.

    Raises UnplayableEnvError, saying how to list the ids, for an unknown id or an
    unplayable game.
    """
    check_env_id(env_id)
    env = gym.make(env_id, render_mode="rgb_array")
    if "rgb_array" not in env.metadata.get("render_modes", []):
        env.close()
        raise UnplayableEnvError(f"{env_id} cannot render RGB frames (render_mode='rgb_array')")
    if not isinstance(env.action_space, gym.spaces.Discrete) or not hasattr(
        env.unwrapped, "get_action_meanings"
    ):
        env.close()
        raise UnplayableEnvError(
            f"{env_id} has no named discrete actions (get_action_meanings()), so no key map: "
            "play Catch-v0 or an Atari game"
        )
    return env


def default_fps(env: gym.Env) -> float:
    """Steps per second at the game's real speed: 60 frames/s for ALE, else render_fps."""
    if env.spec is not None and env.spec.entry_point == ATARI_ENTRY_POINT:
        frameskip = env.spec.kwargs.get("frameskip", 4)
        if isinstance(frameskip, tuple):
            # ALE draws each step's skip uniformly from [low, high).
            frameskip = (frameskip[0] + frameskip[1] - 1) / 2
        return ATARI_FRAMES_PER_SECOND / frameskip
    return float(env.metadata.get("render_fps") or 30)


@dataclass
class PlayStats:
    """What happened in one play session."""

    env_id: str
    scores: list[float] = field(default_factory=list)  # one per finished episode
    steps: int = 0
    # "escape", "window closed", "stopped by SIGINT", "stopped by SIGTERM", "max_episodes", ...
    quit_reason: str = ""

    @property
    def episodes(self) -> int:
        return len(self.scores)

    @property
    def mean_score(self) -> float:
        return float(np.mean(self.scores)) if self.scores else 0.0

    def summary(self) -> str:
        scores = f"mean score {self.mean_score:.3g}" if self.scores else "no finished episode"
        return (
            f"{self.env_id}: {self.episodes} episode(s), {scores}, total "
            f"{sum(self.scores):g}, {self.steps} steps (quit: {self.quit_reason})"
        )


@contextlib.contextmanager
def record_stop_signals() -> Iterator[list[str]]:
    """Within the block, SIGINT and SIGTERM append their name ("SIGTERM") to the list yielded.

    They neither kill the process nor raise, so play() can close its window and say what
    stopped it. Set before the window opens: SDL only installs its own handlers, which turn
    both signals into a window-close event, over the default ones. A signal the parent
    ignores (nohup, a background job) stays ignored, and off the main thread, where Python
    cannot set handlers, nothing changes. The previous handlers come back on exit.
    """
    received: list[str] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return

    def record(signum: int, _frame: object) -> None:
        received.append(signal.Signals(signum).name)

    previous: dict[signal.Signals, Any] = {}
    try:
        for signum in (signal.SIGINT, signal.SIGTERM):
            if signal.getsignal(signum) is not signal.SIG_IGN:
                previous[signum] = signal.signal(signum, record)
        yield received
    finally:
        for signum, handler in previous.items():
            # None: the old handler was not set from Python (no way to put it back).
            signal.signal(signum, signal.SIG_DFL if handler is None else handler)


def play(
    env_id: str = "Catch-v0",
    *,
    fps: float | None = None,
    zoom: int | None = None,
    seed: int | None = None,
    max_episodes: int | None = None,
    max_steps: int | None = None,
    on_step: OnStep | None = None,
) -> PlayStats:
    """Play `env_id` from the keyboard in a pygame window until Esc, close, a signal, a limit.

    One env step per frame at `fps` steps per second (default: the game's real speed);
    the window is the frame scaled by `zoom` (default: about 540 pixels tall). `seed`
    seeds the first reset. `max_episodes`/`max_steps` end the session after that many
    finished episodes/steps. `on_step(env, action, reward)` is called after every step,
    before the frame is shown (tests use it to post key events mid-game).

    Keys are tracked from KEYDOWN/KEYUP events, not `pygame.key.get_pressed()`, so
    posted events count; a key tapped between two frames still acts for one step.
    SIGINT (Ctrl-C) and SIGTERM end the session after the current step, with quit reason
    "stopped by SIGINT"/"stopped by SIGTERM" (see `record_stop_signals`).
    """
    if fps is not None and not fps > 0:
        raise ValueError(f"fps must be positive, got {fps}")
    if zoom is not None and (not isinstance(zoom, int) or zoom < 1):
        raise ValueError(f"zoom must be a positive integer, got {zoom!r}")
    for name, limit in [("max_episodes", max_episodes), ("max_steps", max_steps)]:
        if limit is not None and limit < 1:
            raise ValueError(f"{name} must be positive, got {limit}")
    # Before the env and window exist, so a signal at any point ends the session cleanly.
    with record_stop_signals() as stop_signals:
        env = make_play_env(env_id)
        fps = fps if fps is not None else default_fps(env)
        key_map = build_key_map(env.unwrapped.get_action_meanings())
        stats = PlayStats(env_id)
        score, episode_over = 0.0, False

        def status_text() -> str:
            # The episode being played, or the one just finished while its last frame shows.
            episode = stats.episodes + (0 if episode_over else 1)
            return f"episode {episode}   score {score:g}   total {sum(stats.scores):g}"

        window = None
        try:
            env.reset(seed=seed)
            frame = env.render()
            zoom = zoom or max(1, round(TARGET_WINDOW_HEIGHT / frame.shape[0]))
            # the status line in a bar below the game: over the frame it hid Breakout's score
            window = Window(f"{env_id} (Esc quits)", frame.shape[:2], zoom=zoom, status_bar=True)
            pygame = window.pygame
            key_buttons = _keyboard_buttons(pygame)
            held_keys: set[int] = set()
            window.show(frame, fps=fps, text=status_text())
            while True:
                tapped_keys: set[int] = set()
                for event in pygame.event.get():
                    if event.type == pygame.QUIT:
                        stats.quit_reason = "window closed"
                    elif event.type == pygame.KEYDOWN:
                        if event.key == pygame.K_ESCAPE:
                            stats.quit_reason = "escape"
                        held_keys.add(event.key)
                        tapped_keys.add(event.key)
                    elif event.type == pygame.KEYUP:
                        held_keys.discard(event.key)
                if stop_signals:
                    stats.quit_reason = f"stopped by {stop_signals[0]}"
                if stats.quit_reason:
                    break
                buttons = {
                    key_buttons[key] for key in held_keys | tapped_keys if key in key_buttons
                }
                action = key_map[frozenset(buttons)]
                _, reward, terminated, truncated, _ = env.step(action)
                stats.steps += 1
                score += float(reward)
                if on_step is not None:
                    on_step(env, action, float(reward))
                episode_over = terminated or truncated
                if episode_over:
                    stats.scores.append(score)
                window.show(env.render(), fps=fps, text=status_text())
                if max_episodes is not None and stats.episodes >= max_episodes:
                    stats.quit_reason = "max_episodes"
                    break
                if max_steps is not None and stats.steps >= max_steps:
                    stats.quit_reason = "max_steps"
                    break
                if episode_over:
                    env.reset()
                    score, episode_over = 0.0, False
                    window.show(env.render(), fps=fps, text=status_text())
        finally:
            if window is not None:
                window.close()
            env.close()
    return stats


def _positive(kind: type) -> Callable[[str], Any]:
    """An argparse type: `kind` (int or float) parsed from the text, and above zero."""
    expected = "an integer" if kind is int else "a number"

    def parse(text: str) -> Any:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {expected}, got {text!r}") from None
        if not value > 0:
            raise argparse.ArgumentTypeError(f"must be positive, got {text}")
        return value

    return parse


def build_parser() -> argparse.ArgumentParser:
    """The `catch-play` command line."""
    parser = argparse.ArgumentParser(
        prog="catch-play",
        description="Play Catch-v0 (or an Atari game) yourself. Arrow keys or WASD move, "
        "space is FIRE, Esc or closing the window quits.",
    )
    parser.add_argument("--env", default="Catch-v0", help="env id (default: %(default)s)")
    parser.add_argument(
        "--fps", type=_positive(float), help="steps per second (default: the game's speed)"
    )
    parser.add_argument(
        "--zoom", type=_positive(int), help="window pixels per frame pixel (default: fit ~540px)"
    )
    parser.add_argument("--seed", type=int, help="seed of the first episode")
    parser.add_argument(
        "--episodes", type=_positive(int), help="stop after this many episodes (default: never)"
    )
    parser.add_argument("--list-envs", action="store_true", help="print the env ids and exit")
    return parser


def main(argv: Sequence[str] | None = None) -> None:
    """The `catch-play` command: parse the flags, play, print a summary line.

    Exits 0 however the session ended (Esc, window closed, Ctrl-C, SIGTERM: the summary says
    which), as Ctrl-C always did: the summary is the result, not an error. Bad flags exit 2,
    and so does no display (one line; SDL_VIDEODRIVER=dummy plays headless, as the tests do).
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.list_envs:
        is_atari("Catch-v0")  # registers the ALE ids, if ale-py is installed
        print("\n".join(sorted(gym.registry)))
        return
    # pygame's import banner would bury the controls line.
    os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
    try:
        check_env_id(args.env)
        check_display()  # before the controls line: a game no one can see is not played
        # Flushed: a parent reading the pipe (tests, launchers) sees the game start.
        print(
            f"{args.env}: arrow keys or WASD move, space is FIRE, Esc or closing the window quits.",
            flush=True,
        )
        stats = play(
            args.env, fps=args.fps, zoom=args.zoom, seed=args.seed, max_episodes=args.episodes
        )
    except (UnplayableEnvError, ImportError) as error:
        parser.error(str(error))
    except NoDisplayError as error:  # not a flag's fault: one line, no usage
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        raise SystemExit(2) from None
    print(stats.summary())


if __name__ == "__main__":
    main()
