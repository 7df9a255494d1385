"""The thesis's preprocessing for Catch and for Atari (ALE) games, behind one `make_env`.

Built on `gymnasium.wrappers`; only what Gymnasium lacks is written here:

- `EpisodicLifeEnv`: life loss ends the episode for the learner, but the game is only
  reset at game over (DeepMind's convention). Gymnasium's
  `AtariPreprocessing(terminal_on_life_loss=True)` instead restarts the whole game at
  every lost life, which changes the task.
- `FireResetEnv`: presses FIRE after a reset, for games that wait for it.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
from gymnasium.wrappers import (
    AtariPreprocessing,
    ClipReward,
    FrameStackObservation,
    RecordEpisodeStatistics,
)

import catch_env  # noqa: F401  (registers Catch-v0)

ATARI_ENTRY_POINT = "ale_py.env:AtariEnv"
_ale_registered = False


def _register_ale() -> bool:
    """Register the ALE ids (BreakoutNoFrameskip-v4, ...); False if ale-py is not installed."""
    global _ale_registered
    if not _ale_registered:
        try:
            import ale_py
        except ImportError:
            return False
        gym.register_envs(ale_py)
        _ale_registered = True
    return True


def is_atari(env_id: str) -> bool:
    """Whether `env_id` is an ALE game (registering the ALE ids first, if ale-py is here)."""
    ale_installed = _register_ale()
    try:
        spec = gym.spec(env_id)
    except gym.error.Error:
        # An ALE-looking id with no ale-py installed: say what to install.
        if not ale_installed and ("NoFrameskip" in env_id or env_id.startswith("ALE/")):
            raise ImportError(
                f"{env_id} is an Atari game; install ale-py: pip install 'catch-env[atari]'"
            ) from None
        raise
    return spec.entry_point == ATARI_ENTRY_POINT


class EpisodicLifeEnv(gym.Wrapper):
    """End the learner's episode when a life is lost; reset the game only at game over."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.lives = 0
        self.game_over = True

    def step(self, action: Any) -> tuple[Any, Any, bool, bool, dict[str, Any]]:
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.game_over = terminated or truncated
        lives = self.env.unwrapped.ale.lives()
        if 0 < lives < self.lives:
            terminated = True
        self.lives = lives
        return obs, reward, terminated, truncated, info

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        if self.game_over:
            obs, info = self.env.reset(**kwargs)
        else:
            # Continue the same game from where the life was lost, with a no-op step.
            obs, _, terminated, truncated, info = self.env.step(0)
            if terminated or truncated:
                obs, info = self.env.reset(**kwargs)
        self.game_over = False
        self.lives = self.env.unwrapped.ale.lives()
        return obs, info


class FireResetEnv(gym.Wrapper):
    """Press FIRE after every reset, for games (Breakout, ...) that wait for it."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        meanings = env.unwrapped.get_action_meanings()
        if len(meanings) < 2 or meanings[1] != "FIRE":
            raise ValueError(f"FireResetEnv needs action 1 to be FIRE; this game has {meanings}")

    def reset(self, **kwargs: Any) -> tuple[Any, dict[str, Any]]:
        self.env.reset(**kwargs)
        obs, _, terminated, truncated, info = self.env.step(1)
        if terminated or truncated:
            obs, info = self.env.reset(**kwargs)
        return obs, info


def make_env(
    env_id: str,
    *,
    render_mode: str | None = None,
    frame_stack: int = 4,
    noop_max: int = 30,
    terminal_on_life_loss: bool = False,
    fire_reset: bool = True,
    clip_rewards: bool = True,
    **env_kwargs: Any,
) -> gym.Env:
    """Make `env_id` with the thesis's preprocessing; observations are (4, 84, 84) uint8.

    Catch (any non-ALE id): action repeat 1 and a stack of the last `frame_stack` frames.

    ALE ids (e.g. BreakoutNoFrameskip-v4): `AtariPreprocessing` (action repeat 4 with the
    max of the last two frames, grayscale, 84x84, up to `noop_max` random no-ops at reset),
    optionally life loss as terminal (`EpisodicLifeEnv`) and FIRE on reset (for games with
    a FIRE action), rewards clipped to [-1, 1], and the frame stack. Episodes end at game
    over.

    `RecordEpisodeStatistics` wraps the raw game, so `info["episode"]` at the end of a game
    holds the unclipped score and the length in frames. The stack is cleared on reset (the
    first observation of an episode repeats its first frame). Extra keyword arguments go to
    `gymnasium.make` (e.g. `grid_size` for Catch).
    """
    if isinstance(frame_stack, bool) or not isinstance(frame_stack, int) or frame_stack < 1:
        raise ValueError(f"frame_stack must be a positive integer, got {frame_stack!r}")
    atari = is_atari(env_id)
    if atari:
        # AtariPreprocessing does the frame skipping itself.
        env_kwargs.setdefault("frameskip", 1)
    env = gym.make(env_id, render_mode=render_mode, **env_kwargs)
    env = RecordEpisodeStatistics(env)
    if atari:
        env = AtariPreprocessing(env, noop_max=noop_max, frame_skip=4, screen_size=84)
        if terminal_on_life_loss:
            env = EpisodicLifeEnv(env)
        if fire_reset and "FIRE" in env.unwrapped.get_action_meanings():
            env = FireResetEnv(env)
        if clip_rewards:
            env = ClipReward(env, -1.0, 1.0)
    return FrameStackObservation(env, frame_stack)


def observation_scale(env_id: str) -> float:
    """The thesis's input scaling: Atari frames / 255, Catch frames unscaled (0..255).

    Scaling Catch to [0, 1] makes its gradients so small that RMSprop with epsilon 0.1 in
    the root barely moves (see thesis-notes.md, Catch).
    """
    return 1.0 / 255.0 if is_atari(env_id) else 1.0


__all__ = [
    "EpisodicLifeEnv",
    "FireResetEnv",
    "is_atari",
    "make_env",
    "observation_scale",
]
