"""Catch-v0 in torch, for the agents' batched backend (a3c_runtime.batched): N games of Catch
with the thesis preprocessing (4 stacked 84x84 frames, same-step autoreset), stepped where the
networks run, so that no frame crosses from the host to the device per step.

It is the NumPy env of catch_env under `catch_env.wrappers.make_vector_env` (a
`FrameStackVectorEnv` over a `CatchVectorEnv`), game for game: the same seeds give the same
start states, frames, rewards, terminations and episode statistics (tests/test_batched.py
checks it over many episodes). Two parts stay on the host, each a few numbers per game, never a
frame:

- the start states: each game's NumPy generator, seeded as the NumPy env seeds it, draws its
  start uniforms in the same blocks (catch_env.catch.CatchRules.start_state), and a reset
  uploads the start states (3 integers per game) it needs;
- the ball's row: it falls one row per step whatever the actions, so which games end at a step
  is known on the host without reading the device.

The rules and the drawing tables are catch_env's (CatchRules); only the default 84x84 pixel
frames are drawn here. catch_env itself does not need torch: importing it does not import this
module, which needs torch (`pip install "catch-env[torch]"`).
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium.utils import seeding

try:
    import torch
except ImportError as e:  # catch_env installs without torch; this module alone needs it
    raise ImportError(
        'catch_env.torch_catch needs torch: pip install "catch-env[torch]" (or torch)'
    ) from e

from catch_env.catch import (
    ACTION_DIRECTION,
    BALL_START_ROW,
    MAX_BALL_SPEED,
    OBS_SIZE,
    START_BUFFER,
    CatchRules,
    vector_seeds,
)


class TorchCatchVectorEnv:
    """`num_envs` games of Catch-v0 (the thesis's geometry, pixel frames) behind the stacked
    frames of `catch_env.wrappers.make_vector_env("Catch-v0", num_envs)`, on `device`.

    `reset(seed)` -> observations (N, frame_stack, 84, 84) uint8; `step(actions)` ->
    (observations, rewards (N,) float32, terminated (N,) bool, ended (N,) NumPy bool): an ended
    game's observation is already its next game's first (same-step autoreset), its last stack in
    `final_obs`, its score and length in `final_returns` and `final_lengths` (device tensors,
    read where `ended`). Catch never truncates. The observations are this env's own
    buffer, overwritten by the next step."""

    def __init__(self, num_envs: int, device: str | torch.device = "cpu", frame_stack: int = 4):
        if num_envs < 1:
            raise ValueError(f"num_envs must be >= 1, got {num_envs}")
        self.num_envs, self.device = num_envs, torch.device(device)
        self.rules = rules = CatchRules()
        # the NumPy env's tables: the next (column, speed) of every (column, speed), the next
        # paddle centre of every (centre, action)
        size, speeds = rules.grid_size, 2 * MAX_BALL_SPEED + 1
        next_col, next_vx = rules.move_ball(
            np.arange(size)[:, None], np.arange(-MAX_BALL_SPEED, MAX_BALL_SPEED + 1)[None, :]
        )
        next_paddle = rules.move_paddle(np.arange(size)[:, None], np.array(ACTION_DIRECTION))
        self._speeds, self._actions = speeds, len(ACTION_DIRECTION)
        to_device = lambda a: torch.as_tensor(np.ascontiguousarray(a), device=self.device)  # noqa: E731
        self._next_ball_col, self._next_ball_vx = (
            to_device(next_col.ravel()),
            to_device(next_vx.ravel()),
        )
        self._next_paddle = to_device(next_paddle.ravel())
        # pixel p shows cell pixel_cell[p] (the NumPy env's sprites cover exactly these pixels)
        self._pixel_cell = to_device(rules.pixel_cell.astype(np.int64))
        self._paddle_rows = self._pixel_cell == rules.paddle_row  # (84,)
        n = num_envs
        self.ball_row = np.full(n, BALL_START_ROW, dtype=np.int64)  # host: known without a sync
        self._ball_row = torch.full((n,), BALL_START_ROW, device=self.device)  # and the device's
        self.ball_col = torch.zeros(n, dtype=torch.int64, device=self.device)
        self.ball_vx = torch.zeros_like(self.ball_col)
        self.paddle = torch.zeros_like(self.ball_col)
        self.stack = torch.zeros((n, frame_stack, OBS_SIZE, OBS_SIZE), dtype=torch.uint8,
                                 device=self.device)  # fmt: skip
        self.episode_returns = torch.zeros(n, dtype=torch.float64, device=self.device)
        self.episode_lengths = torch.zeros(n, dtype=torch.int64, device=self.device)
        self.final_obs = torch.zeros_like(self.stack)
        self.final_returns = torch.zeros_like(self.episode_returns)
        self.final_lengths = torch.zeros_like(self.episode_lengths)
        self._rngs = [seeding.np_random()[0] for _ in range(n)]
        self._starts = np.zeros((n, START_BUFFER, 3))
        self._starts_used = np.full(n, START_BUFFER)
        self._reset_before = False

    # -- the NumPy env's start states, on the host ------------------------------------------
    def _start_games(self, envs: np.ndarray) -> None:
        for env in envs[self._starts_used[envs] == START_BUFFER]:
            self._starts[env] = self._rngs[env].random((START_BUFFER, 3))
            self._starts_used[env] = 0
        uniforms = self._starts[envs, self._starts_used[envs]]
        self._starts_used[envs] += 1
        col, vx, paddle = self.rules.start_state(uniforms)
        index = torch.as_tensor(envs, device=self.device)
        start = torch.as_tensor(np.stack([col, vx, paddle]), device=self.device)
        self.ball_col[index], self.ball_vx[index], self.paddle[index] = start.unbind(0)
        self.ball_row[envs] = BALL_START_ROW
        self._ball_row[index] = BALL_START_ROW

    def _frames(self) -> torch.Tensor:
        """Every game's 84x84 frame, (N, 84, 84) uint8: the ball's cell and the paddle's."""
        cell = self._pixel_cell
        ball_rows = cell[None, :] == self._ball_row[:, None]
        ball_cols = cell[None, :] == self.ball_col[:, None]
        paddle_cols = (cell[None, :] - self.paddle[:, None]).abs() <= self.rules.paddle_half
        ball = ball_rows[:, :, None] & ball_cols[:, None, :]
        paddle = self._paddle_rows[None, :, None] & paddle_cols[:, None, :]
        return (ball | paddle).to(torch.uint8) * 255

    def reset(self, seed: int | list[int] | None = None) -> torch.Tensor:
        """Every game from its start; seed as Gymnasium's vector envs take it (s: game i gets
        s + i; a list: one per game)."""
        if seed is not None:
            self._rngs = [seeding.np_random(s)[0] for s in vector_seeds(seed, self.num_envs)]
            self._starts_used[:] = START_BUFFER
        self._start_games(np.arange(self.num_envs))
        self.stack[:] = self._frames()[:, None]
        self.episode_returns.zero_()
        self.episode_lengths.zero_()
        self._reset_before = True
        return self.stack

    def step(
        self, actions: torch.Tensor
    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, np.ndarray]:
        if not self._reset_before:
            raise RuntimeError("Cannot step before reset(): call reset() first.")
        ball = self.ball_col * self._speeds + (self.ball_vx + MAX_BALL_SPEED)
        self.ball_row += 1
        self._ball_row += 1
        self.ball_col, self.ball_vx = self._next_ball_col[ball], self._next_ball_vx[ball]
        self.paddle = self._next_paddle[self.paddle * self._actions + actions.to(torch.int64)]
        ended = self.ball_row == self.rules.paddle_row  # Catch's only episode end
        terminated = self._ball_row == self.rules.paddle_row  # (ended, without an upload)
        caught = (self.ball_col - self.paddle).abs() <= self.rules.paddle_half
        rewards = (terminated & caught).to(torch.float32)
        frames = self._frames()
        self.stack[:, :-1] = self.stack[:, 1:].clone()
        self.stack[:, -1] = frames
        self.episode_returns += rewards
        self.episode_lengths += 1
        if ended.any():
            games = np.flatnonzero(ended)
            index = torch.as_tensor(games, device=self.device)
            self.final_obs[index] = self.stack[index]
            self.final_returns[index] = self.episode_returns[index]
            self.final_lengths[index] = self.episode_lengths[index]
            self._start_games(games)
            self.stack[index] = self._frames()[index][:, None]
            self.episode_returns[index] = 0.0
            self.episode_lengths[index] = 0
        return self.stack, rewards, terminated, ended

    # -- the NumPy env's state, for checkpoints that the process backend resumes ---------------
    def numpy_state(self, env: int) -> dict[str, Any]:
        """Game `env` as `make_vector_env("Catch-v0", 1).get_state()` holds it (a
        FrameStackVectorEnv over a one-game CatchVectorEnv): a checkpoint that carries it
        resumes in the script's own loop, and `set_numpy_state` reads it back."""
        stack = self.stack[env].cpu().numpy()
        inner = {
            "ball_row": np.array([int(self.ball_row[env])]),
            "ball_col": np.array([int(self.ball_col[env])]),
            "ball_vx": np.array([int(self.ball_vx[env])]),
            "paddle": np.array([int(self.paddle[env])]),
            "_needs_reset": np.zeros(1, dtype=bool),  # (the wrapper resets an ended game at once)
            "_starts": self._starts[env][None].copy(),
            "_starts_used": self._starts_used[env : env + 1].copy(),
            "rngs": [self._rngs[env].bit_generator.state],
        }
        return {
            "stack": stack[None].copy(),
            "returns": np.array([float(self.episode_returns[env])]),
            "lengths": np.array([int(self.episode_lengths[env])]),
            "env": inner,
        }

    def set_numpy_state(self, env: int, state: dict[str, Any]) -> None:
        """Game `env` from `numpy_state`'s form (a resumed run's checkpoint)."""
        inner = state["env"]
        self.ball_row[env] = self._ball_row[env] = int(np.asarray(inner["ball_row"])[0])
        self.ball_col[env] = int(np.asarray(inner["ball_col"])[0])
        self.ball_vx[env] = int(np.asarray(inner["ball_vx"])[0])
        self.paddle[env] = int(np.asarray(inner["paddle"])[0])
        self._starts[env] = np.asarray(inner["_starts"])[0]
        self._starts_used[env] = int(np.asarray(inner["_starts_used"])[0])
        rng = np.random.Generator(np.random.PCG64())
        rng.bit_generator.state = inner["rngs"][0]
        self._rngs[env] = rng
        self.stack[env] = torch.as_tensor(np.asarray(state["stack"])[0], device=self.device)
        self.episode_returns[env] = float(np.asarray(state["returns"])[0])
        self.episode_lengths[env] = int(np.asarray(state["lengths"])[0])
        self._reset_before = True


class NumpyStateView:
    """One game of a TorchCatchVectorEnv with the `get_state()` and `set_state()` of the NumPy
    env it stands for, so that a3c_runtime.snapshots keeps and restores it in a checkpoint as
    the script's env."""

    def __init__(self, envs: TorchCatchVectorEnv, env: int):
        self.envs, self.env = envs, env

    def get_state(self) -> dict[str, Any]:
        return self.envs.numpy_state(self.env)

    def set_state(self, state: dict[str, Any]) -> None:
        self.envs.set_numpy_state(self.env, state)
