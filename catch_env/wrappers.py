"""The thesis's preprocessing for Catch and for Atari (ALE) games, behind one `make_env`.

Built on `gymnasium.wrappers`; only what Gymnasium lacks is written here:

- `EpisodicLifeEnv`: life loss ends the episode for the learner, but the game is only
  reset at game over (DeepMind's convention). Gymnasium's
  `AtariPreprocessing(terminal_on_life_loss=True)` instead restarts the whole game at
  every lost life, which changes the task.
- `FireResetEnv`: presses FIRE after a reset, for games that wait for it.
- `FrameStackVectorEnv`: the frame stack for Catch's NumPy vector env, with same-step
  autoreset (Gymnasium has no vector frame stack).

`make_vector_env` gives N preprocessed envs behind one Gymnasium `VectorEnv`.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.vector import AutoresetMode, SyncVectorEnv, VectorEnv, VectorWrapper
from gymnasium.vector.utils import batch_space
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
    """Register the ALE ids (BreakoutNoFrameskip-v4, ...); False if ale-py is not installed.
    ALE's log level becomes Warning: its warnings and errors still show, but not the banner that
    every new emulator prints at Info level to stderr (once per process)."""
    global _ale_registered
    if not _ale_registered:
        try:
            import ale_py
        except ImportError:
            return False
        ale_py.ALEInterface.setLoggerMode(ale_py.LoggerMode.Warning)
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


class FrameStackVectorEnv(VectorWrapper):
    """The last `frame_stack` frames of each env of a vector env, with same-step autoreset: the
    step that ends an env's episode returns the first observation of its next one and puts the
    last observation in `infos["final_obs"]`, as `SyncVectorEnv(autoreset_mode=SAME_STEP)`
    does. It wraps a next-step-autoreset env whose `reset` takes `options={"reset_mask": m}`
    (Catch's `CatchVectorEnv`), and matches a same-step `SyncVectorEnv` of `make_env` envs
    (`FrameStackObservation` per env, the stack cleared on reset) frame for frame.

    `infos` holds only what ended episodes give: `final_obs` and `final_info["episode"]` (the
    episode's reward sum "r" and length "l"), each with its `_`-mask, in `SyncVectorEnv`'s
    layout. The returned observations are the wrapper's own buffer, overwritten by the next
    step (as `copy=False` in Gymnasium's vector envs).
    """

    def __init__(self, env: VectorEnv, frame_stack: int = 4) -> None:
        super().__init__(env)
        num_envs, frame_shape = env.num_envs, env.single_observation_space.shape
        self.single_observation_space = spaces.Box(
            0, 255, (frame_stack, *frame_shape), dtype=np.uint8
        )
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.metadata = {**env.metadata, "autoreset_mode": AutoresetMode.SAME_STEP}
        self._stack = np.zeros((num_envs, frame_stack, *frame_shape), dtype=np.uint8)
        self._returns = np.zeros(num_envs, dtype=np.float64)
        self._lengths = np.zeros(num_envs, dtype=np.int64)

    def get_state(self) -> dict[str, Any]:
        """The stacks, the episodes' running sums and the wrapped env's `get_state()`, as NumPy
        arrays and plain numbers: a copy, for `set_state`."""
        return {
            "stack": self._stack.copy(),
            "returns": self._returns.copy(),
            "lengths": self._lengths.copy(),
            "env": self.env.get_state(),
        }

    def set_state(self, state: dict[str, Any]) -> None:
        """Go on from `get_state()`'s copy, taken from an env made with the same arguments; a
        state of another shape is a ValueError."""
        parts = {"_stack": state["stack"], "_returns": state["returns"],
                 "_lengths": state["lengths"]}  # fmt: skip
        for name, value in parts.items():
            if np.shape(value) != getattr(self, name).shape:
                raise ValueError(f"state {name[1:]!r} has shape {np.shape(value)}")
        self.env.set_state(state["env"])
        for name, value in parts.items():
            getattr(self, name)[...] = value

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = self.env.reset(seed=seed, options=options)
        # options={"reset_mask": m} resets only the envs in m; the others keep their stacks
        mask = np.ones(self.num_envs, dtype=bool)
        if options is not None and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], dtype=bool)
        self._stack[mask] = obs[mask][:, None]
        self._returns[mask], self._lengths[mask] = 0.0, 0
        return self._stack, info

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        obs, rewards, terminated, truncated, _ = self.env.step(actions)
        self._stack[:, :-1] = self._stack[:, 1:]  # NumPy buffers the overlapping copy
        self._stack[:, -1] = obs
        self._returns += rewards
        self._lengths += 1
        ended = terminated | truncated
        if not ended.any():
            return self._stack, rewards, terminated, truncated, {}
        final_obs = np.full(self.num_envs, None, dtype=object)
        for i in np.flatnonzero(ended):
            final_obs[i] = self._stack[i].copy()
        episode = {"r": self._returns.copy(), "l": self._lengths.copy()}
        infos = {
            "final_obs": final_obs,
            "_final_obs": ended.copy(),
            "final_info": {"episode": episode, "_episode": ended.copy()},
            "_final_info": ended.copy(),
        }
        obs, _ = self.env.reset(options={"reset_mask": ended})
        self._stack[ended] = obs[ended][:, None]
        self._returns[ended], self._lengths[ended] = 0.0, 0
        return self._stack, rewards, terminated, truncated, infos


class AtariNativeVectorEnv(VectorWrapper):
    """ALE games on ale-py's C++ vector env (`ale_py.vector_env.AtariVectorEnv`, ported from
    EnvPool), with `make_env`'s contract: observations (num_envs, frame_stack, 84, 84) uint8,
    same-step autoreset with the last observation in `infos["final_obs"]`, the raw game score
    and length in `infos["final_info"]["episode"]` ("r", "l"), rewards clipped to [-1, 1].

    The emulators, the action repeat of 4 with the max of the last two frames, the grayscale
    84x84 resize, the no-op starts and FIRE on reset run in C++ on `num_threads` threads. The
    frame stack, the clipping and the episode statistics are kept here, so that the score is
    the unclipped one and an episode's first observation repeats its first frame, as in
    `make_env`. Against a same-step `SyncVectorEnv` of `make_env` envs on the same seeds and
    actions (tests/test_wrappers.py checks it), the frames are identical (the resize is the
    same) with these differences:

    - FIRE on reset lasts one frame here, one action (4 frames) there, so with `fire_reset`
      the two games run a few frames apart from the first step on;
    - the no-op starts (up to noop_max) draw from ALE's random stream, not Gymnasium's;
    - with `terminal_on_life_loss` the game goes on from the frame of the lost life, where
      `EpisodicLifeEnv` first plays one no-op action.

    Rewards, terminations, the final observations and the episodes' scores and lengths (in
    frames, the no-ops and FIRE included) are the same.
    """

    def __init__(
        self,
        env_id: str,
        num_envs: int,
        *,
        frame_stack: int = 4,
        num_threads: int = 1,
        noop_max: int = 30,
        terminal_on_life_loss: bool = False,
        fire_reset: bool = True,
        clip_rewards: bool = True,
    ) -> None:
        from ale_py.vector_env import AtariVectorEnv

        spec_kwargs = gym.spec(env_id).kwargs
        native = AtariVectorEnv(
            spec_kwargs["game"],
            num_envs,
            num_threads=num_threads,
            repeat_action_probability=spec_kwargs.get("repeat_action_probability", 0.0),
            full_action_space=spec_kwargs.get("full_action_space", False),
            max_num_frames_per_episode=spec_kwargs.get("max_num_frames_per_episode", 108_000),
            autoreset_mode=AutoresetMode.SAME_STEP,
            stack_num=1,
            frameskip=4,
            noop_max=noop_max,
            use_fire_reset=fire_reset,
            life_loss_info=terminal_on_life_loss,
            reward_clipping=False,
        )
        super().__init__(native)
        self.single_observation_space = spaces.Box(0, 255, (frame_stack, 84, 84), dtype=np.uint8)
        self.observation_space = batch_space(self.single_observation_space, num_envs)
        self.metadata = {**native.metadata, "autoreset_mode": AutoresetMode.SAME_STEP}
        self.clip_rewards = clip_rewards
        self._stack = np.zeros((num_envs, frame_stack, 84, 84), dtype=np.uint8)
        self._returns = np.zeros(num_envs, dtype=np.float64)
        self._frames = np.zeros(num_envs, dtype=np.int64)
        self._lives = np.zeros(num_envs, dtype=np.int64)
        self._frame_number = np.zeros(num_envs, dtype=np.int64)

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        mask = np.ones(self.num_envs, dtype=bool)
        if options is not None and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], dtype=bool)
        if isinstance(seed, list):
            seed = None if all(s is None for s in seed) else np.asarray(seed)
        elif seed is not None:
            seed = np.arange(seed, seed + int(mask.sum()))  # env i gets seed + i, as Gymnasium's
        if seed is not None:
            seed = seed.astype(np.int64) % 2**31  # ALE takes a C int; Gymnasium's go to 2**32
        obs, info = self.env.reset(seed=seed, options=options)
        self._stack[mask] = obs[mask]  # (n, 1, 84, 84) repeated along the stack
        self._returns[mask] = 0.0
        self._frames[mask] = info["episode_frame_number"][mask]
        self._lives[mask] = info["lives"][mask]
        self._frame_number[mask] = info["frame_number"][mask]
        return self._stack, {}

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        actions = np.asarray(actions, dtype=np.int64)
        obs, rewards, terminated, truncated, info = self.env.step(actions)
        rewards = rewards.astype(np.float64)
        self._stack[:, :-1] = self._stack[:, 1:]  # NumPy buffers the overlapping copy
        self._stack[:, -1] = obs[:, 0]
        self._returns += rewards
        # frame_number is ALE's count over all episodes: its increase is this action's frames
        # plus, for an env that was reset, the reset's no-ops and FIRE (its episode_frame_number)
        step_frames = info["frame_number"] - self._frame_number
        self._frame_number[:] = info["frame_number"]
        self._frames += step_frames
        if self.clip_rewards:
            rewards = np.clip(rewards, -1.0, 1.0)
        ended = terminated | truncated
        if not ended.any():
            self._lives[:] = info["lives"]
            return self._stack, rewards, terminated, truncated, {}
        # A lost life (terminal_on_life_loss) ends the learner's episode but not the game:
        # the env was not reset, it shows fewer lives than before and some left.
        life_lost = terminated & (info["lives"] < self._lives) & (info["lives"] > 0)
        game_over = ended & ~life_lost
        final_obs = np.full(self.num_envs, None, dtype=object)
        for i in np.flatnonzero(ended):
            final_obs[i] = self._stack[i].copy()
            if game_over[i]:
                final_obs[i][-1] = info["final_obs"][i, 0]
        reset_frames = np.where(game_over, info["episode_frame_number"], 0)
        episode = {"r": self._returns.copy(), "l": self._frames - reset_frames}
        infos = {
            "final_obs": final_obs,
            "_final_obs": ended.copy(),
            "final_info": {"episode": episode, "_episode": game_over.copy()},
            "_final_info": ended.copy(),
        }
        self._stack[ended] = obs[ended]  # the next episode's first frame, repeated
        self._returns[game_over] = 0.0
        self._frames[game_over] = info["episode_frame_number"][game_over]
        self._lives[:] = info["lives"]
        return self._stack, rewards, terminated, truncated, infos


def make_vector_env(
    env_id: str,
    num_envs: int,
    *,
    frame_stack: int = 4,
    backend: str = "native",
    num_threads: int = 1,
    **kwargs: Any,
) -> VectorEnv:
    """`num_envs` envs of `env_id` with `make_env`'s preprocessing behind one `VectorEnv`, with
    same-step autoreset: an ended episode's last observation and statistics are in
    `infos["final_obs"]` and `infos["final_info"]["episode"]` ("r": the raw score, "l"), each
    with its `_`-mask, and the returned observation is already the next episode's first.
    Observations (num_envs, frame_stack, 84, 84) uint8, overwritten by the next step.

    Catch: Catch's NumPy vector env (`gym.make_vec`) under `FrameStackVectorEnv` (keyword
    arguments go to `gym.make_vec`). ALE ids: with `backend="native"` (the default),
    `AtariNativeVectorEnv`, ale-py's C++ vector env on `num_threads` emulator threads; with
    `backend="python"`, a `SyncVectorEnv` of `make_env` envs, the emulators stepping one after
    another in this process. Keyword arguments go to either (`noop_max`,
    `terminal_on_life_loss`, `fire_reset`, `clip_rewards`).
    """
    if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
        raise ValueError(f"num_envs must be a positive integer, got {num_envs!r}")
    if backend not in ("native", "python"):
        raise ValueError(f"backend must be 'native' or 'python', got {backend!r}")
    atari = is_atari(env_id)
    if not atari and gym.spec(env_id).vector_entry_point is not None:
        env = gym.make_vec(env_id, num_envs=num_envs, copy=False, **kwargs)
        return FrameStackVectorEnv(env, frame_stack)
    if atari and backend == "native":
        return AtariNativeVectorEnv(
            env_id, num_envs, frame_stack=frame_stack, num_threads=num_threads, **kwargs
        )
    return SyncVectorEnv(
        [lambda: make_env(env_id, frame_stack=frame_stack, **kwargs) for _ in range(num_envs)],
        copy=False,
        autoreset_mode=AutoresetMode.SAME_STEP,
    )


def observation_scale(env_id: str) -> float:
    """The thesis's input scaling: Atari frames / 255, Catch frames unscaled (0..255).

    Scaling Catch to [0, 1] makes its gradients so small that RMSprop with epsilon 0.1 in
    the root barely moves (see thesis-notes.md, Catch).
    """
    return 1.0 / 255.0 if is_atari(env_id) else 1.0


__all__ = [
    "AtariNativeVectorEnv",
    "EpisodicLifeEnv",
    "FireResetEnv",
    "FrameStackVectorEnv",
    "is_atari",
    "make_env",
    "make_vector_env",
    "observation_scale",
]
