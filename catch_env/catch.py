"""Catch: the thesis's bouncing-ball test bed (section 5.4), and its NumPy vector twin.

The rules, the random start states and the drawing tables live once, in `CatchRules`;
`CatchEnv` plays one game with Python scalars (fast for a single env) and
`CatchVectorEnv` plays N games with NumPy arrays. Both draw incrementally: the canvas
only ever holds the ball and the paddle, so a step erases the ball's old cell, rewrites
the paddle's band of rows and draws the ball's new cell instead of redrawing the frame.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal, SupportsFloat

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

ACTION_MEANINGS = ("NOOP", "LEFT", "RIGHT")
# Paddle direction per action, in grid columns.
ACTION_DIRECTION = (0, -1, 1)
BALL_START_ROW = 4
# The paddle sits on row grid_size - 5, leaving four empty rows below it (row 19 of 24).
PADDLE_ROW_FROM_BOTTOM = 5
MAX_BALL_SPEED = 2
OBS_SIZE = 84
OBS_TYPES = ("pixels", "grid")
ON, OFF = 255, 0
START_BUFFER = 64  # start states a vector env draws per game at a time (its default)

_VALID_ACTIONS = ", ".join(f"{i} {name}" for i, name in enumerate(ACTION_MEANINGS))
# What CatchVectorEnv holds per env, in frames (measured with tracemalloc): the batched
# observation space's bounds and their masks, the canvas and the copy a step returns.
VECTOR_FRAMES_PER_ENV = 8


def available_memory() -> int | None:
    """The bytes this process can still allocate without swapping (Linux: MemAvailable, capped
    by a cgroup v2 memory limit), or None where it cannot be told."""
    available = None
    with contextlib.suppress(OSError, ValueError, IndexError), open("/proc/meminfo") as f:
        for line in f:
            if line.startswith("MemAvailable:"):
                available = int(line.split()[1]) * 1024
    if available is None and hasattr(os, "sysconf"):
        with contextlib.suppress(OSError, ValueError):
            available = os.sysconf("SC_AVPHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")
    with contextlib.suppress(OSError, ValueError):  # a container's limit, if lower
        with open("/sys/fs/cgroup/memory.max") as f:
            limit = f.read().strip()
        with open("/sys/fs/cgroup/memory.current") as f:
            used = int(f.read())
        if limit != "max":
            room = max(int(limit) - used, 0)
            available = room if available is None else min(available, room)
    return available


def format_bytes(count: float) -> str:
    """1.5 GiB, 820 MiB: a memory size for a message."""
    for unit, size in (("TiB", 2**40), ("GiB", 2**30), ("MiB", 2**20)):
        if count >= size:
            return f"{count / size:.3g} {unit}"
    return f"{count / 2**10:.3g} KiB"


def vector_seeds(seed: Any, num_envs: int) -> list[int | None]:
    """Gymnasium's vector-env seeding (SyncVectorEnv): None gives every env a random seed; an
    integer s (a NumPy integer too) gives env i the seed s + i; a sequence gives one seed per
    env. Anything else gets Gymnasium's own error, as a single env's reset gives it."""
    if seed is None:
        return [None] * num_envs
    if isinstance(seed, (int, np.integer)):
        seeds = [int(seed) + i for i in range(num_envs)]
    elif isinstance(seed, (Sequence, np.ndarray)) and not isinstance(seed, (str, bytes)):
        seeds = [int(s) if isinstance(s, np.integer) else s for s in seed]
        if len(seeds) != num_envs:
            raise ValueError(
                "If seeds are passed as a list the length must match "
                f"num_envs={num_envs} but got length={len(seeds)}."
            )
    else:
        seeding.np_random(seed)  # raises Gymnasium's error for this seed
        raise AssertionError("unreachable: np_random refuses any other seed")
    return seeds  # (np_random gives Gymnasium's error for a negative or non-integer one)


def _check_int(name: str, value: Any, low: int, high: int, extra: str = "") -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)):
        raise ValueError(f"{name} must be an integer in [{low}, {high}]{extra}, got {value!r}")
    if not low <= value <= high:
        raise ValueError(f"{name} must be in [{low}, {high}]{extra}, got {value}")
    return int(value)


@dataclass(frozen=True)
class CatchRules:
    """The game's geometry, dynamics and drawing tables, shared by the single and vector env.

    The dynamics are written once with arithmetic that works on Python ints and on NumPy
    arrays alike, so both envs step with the same code.
    """

    grid_size: int = 24
    paddle_width: int = 5
    paddle_speed: int = 2
    obs_type: str = "pixels"

    def __post_init__(self) -> None:
        size = _check_int("grid_size", self.grid_size, 10, OBS_SIZE)
        _check_int("paddle_width", self.paddle_width, 1, size, " and odd")
        if self.paddle_width % 2 == 0:
            raise ValueError(
                f"paddle_width must be odd (the paddle has a centre cell), got {self.paddle_width}"
            )
        _check_int("paddle_speed", self.paddle_speed, 1, size - 1)
        if self.obs_type not in OBS_TYPES:
            raise ValueError(f"obs_type must be one of {OBS_TYPES}, got {self.obs_type!r}")
        # Drawing tables: cell c covers canvas pixels [cell_start[c], cell_stop[c]).
        # The 84x84 frame is the grid upscaled by nearest neighbour (pixel p shows cell
        # floor(p * grid_size / 84)), so cells are crisp blocks of 3 or 4 pixels.
        side = self.obs_side
        pixel_cell = np.arange(side) * size // side
        cell_start = np.searchsorted(pixel_cell, np.arange(size), side="left")
        cell_stop = np.searchsorted(pixel_cell, np.arange(size), side="right")
        # The paddle's row of pixels for every centre column (the single env's drawing).
        paddle_line = np.zeros((size, side), dtype=np.uint8)
        for centre in range(self.paddle_min, self.paddle_max + 1):
            lo, hi = centre - self.paddle_half, centre + self.paddle_half
            paddle_line[centre, cell_start[lo] : cell_stop[hi]] = ON

        # Sprites (the vector env's drawing): the flat canvas offsets (row * side + column)
        # of the ball at every cell and of the paddle at every centre, each padded to a fixed
        # length by repeating offsets, so all N games are drawn with one scatter.
        def offsets(row: int, first_col: int, last_col: int) -> np.ndarray:
            rows = np.arange(cell_start[row], cell_stop[row])
            cols = np.arange(cell_start[first_col], cell_stop[last_col])
            return (rows[:, None] * side + cols[None, :]).ravel()

        def sprites(blocks: list[np.ndarray]) -> np.ndarray:
            return np.stack([np.resize(b, max(map(len, blocks))) for b in blocks])

        # Indexed by row * size + column.
        ball_sprite = sprites([offsets(r, c, c) for r in range(size) for c in range(size)])
        # Centres off the valid range are never used; clamping keeps them well-formed.
        half, last = self.paddle_half, size - 1
        paddle_sprite = sprites(
            [offsets(self.paddle_row, max(c - half, 0), min(c + half, last)) for c in range(size)]
        )
        for name, table in [
            ("pixel_cell", pixel_cell),
            ("cell_start", cell_start),
            ("cell_stop", cell_stop),
            ("paddle_line", paddle_line),
            ("ball_sprite", ball_sprite),
            ("paddle_sprite", paddle_sprite),
        ]:
            table.setflags(write=False)
            object.__setattr__(self, name, table)

    # Geometry -------------------------------------------------------------------------
    @property
    def obs_side(self) -> int:
        return OBS_SIZE if self.obs_type == "pixels" else self.grid_size

    @property
    def paddle_row(self) -> int:
        return self.grid_size - PADDLE_ROW_FROM_BOTTOM

    @property
    def paddle_half(self) -> int:
        return self.paddle_width // 2

    @property
    def paddle_min(self) -> int:
        return self.paddle_half

    @property
    def paddle_max(self) -> int:
        return self.grid_size - 1 - self.paddle_half

    @property
    def episode_length(self) -> int:
        return self.paddle_row - BALL_START_ROW

    def observation_space(self) -> spaces.Box:
        return spaces.Box(OFF, ON, (self.obs_side, self.obs_side), np.uint8)

    # Dynamics (Python ints or NumPy arrays) -------------------------------------------
    def start_state(self, uniforms: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Ball column, ball speed and paddle centre from three U[0, 1) draws per game.

        Drawing floats (one 64-bit draw each) rather than bounded integers keeps a batch of
        draws identical to the same draws made one game at a time, which is what lets the
        vector env reproduce N single envs exactly.
        """
        u = np.asarray(uniforms)
        ball_col = (u[..., 0] * self.grid_size).astype(np.int64)
        ball_vx = (u[..., 1] * (2 * MAX_BALL_SPEED + 1)).astype(np.int64) - MAX_BALL_SPEED
        span = self.paddle_max - self.paddle_min + 1
        paddle = self.paddle_min + (u[..., 2] * span).astype(np.int64)
        return ball_col, ball_vx, paddle

    def move_ball(self, col, vx):
        """Move one column step of vx, bouncing off the side walls (reflect and flip vx)."""
        col = col + vx
        right, left = col > self.grid_size - 1, col < 0
        col = col - 2 * (col - (self.grid_size - 1)) * right - 2 * col * left
        return col, vx - 2 * vx * (right | left)

    def move_paddle(self, centre, direction):
        """Move paddle_speed cells in direction; a move that would leave the grid does nothing."""
        target = centre + self.paddle_speed * direction
        inside = (target >= self.paddle_min) & (target <= self.paddle_max)
        return centre + (target - centre) * inside

    def caught(self, ball_col, paddle):
        return abs(ball_col - paddle) <= self.paddle_half

    def to_pixels(self, grid: np.ndarray) -> np.ndarray:
        """Upscale a grid image (..., G, G) to the 84x84 frame by nearest neighbour."""
        if self.obs_type == "pixels":
            return grid
        cells = np.arange(OBS_SIZE) * self.grid_size // OBS_SIZE
        return grid[..., cells[:, None], cells[None, :]]


NO_WINDOW = "no window"  # CatchEnv._window where none can open (said once, at the first render)


def _action_error(action: Any) -> ValueError:
    return ValueError(f"Invalid action {action!r}: valid actions are {_VALID_ACTIONS}.")


class CatchEnv(gym.Env[np.ndarray, np.int64]):
    """Catch, as in section 5.4 of the thesis.

    A ball starts on row 4 of a 24x24 grid at a uniformly random column, with horizontal
    speed vx uniform in {-2, ..., 2}. Each step it falls one row and moves vx columns,
    bouncing off the side walls. A 5-cell paddle on row 19 starts with its centre uniform
    in 2..21 and moves 2 cells per step.

    ## Action space
    `Discrete(3)`: 0 NOOP, 1 LEFT, 2 RIGHT (ALE order, so no-op based tools work). A move
    that would take the paddle off the grid does nothing.

    ## Observation space
    `obs_type="pixels"` (default): `Box(0, 255, (84, 84), uint8)`, the grid upscaled by
    nearest neighbour, ball and paddle 255 on a 0 background. `obs_type="grid"`:
    `Box(0, 255, (24, 24), uint8)`, one value per cell with the same colours.

    ## Rewards
    1 when the ball reaches the paddle row within `paddle_width // 2` columns of the
    paddle's centre, else 0. Every other step gives 0.

    ## Episode end
    Terminates when the ball reaches the paddle row: after exactly 15 steps with the
    default geometry (`grid_size - 9` in general). Never truncates. Stepping a terminated
    episode without `reset()` raises `RuntimeError`.

    ## Arguments
    `gym.make("Catch-v0", grid_size=24, paddle_width=5, paddle_speed=2, obs_type="pixels",
    render_mode=None)`. The defaults are the thesis values; an invalid value raises
    `ValueError` naming the valid range. `render_mode="rgb_array"` returns the 84x84 frame
    as HxWx3 uint8; `"human"` shows it in a pygame window, created at the first render. Where
    no window can open (no display and SDL_VIDEODRIVER not set to a headless driver, or no
    pygame) human rendering shows nothing and warns once saying why, as Gymnasium's pygame envs
    play on unseen without a display; so `gymnasium.utils.env_checker.check_env` passes there.
    """

    metadata = {"render_modes": ["human", "rgb_array"], "render_fps": 10}

    def __init__(
        self,
        grid_size: int = 24,
        paddle_width: int = 5,
        paddle_speed: int = 2,
        obs_type: Literal["pixels", "grid"] = "pixels",
        render_mode: str | None = None,
    ) -> None:
        self.rules = CatchRules(grid_size, paddle_width, paddle_speed, obs_type)
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be None or one of {self.metadata['render_modes']}, "
                f"got {render_mode!r}"
            )
        self.render_mode = render_mode
        self.observation_space = self.rules.observation_space()
        self.action_space = spaces.Discrete(len(ACTION_MEANINGS))
        self._canvas = np.zeros(self.observation_space.shape, dtype=np.uint8)
        # Python lists: indexing them is several times faster than NumPy scalars.
        self._cell_start = self.rules.cell_start.tolist()
        self._cell_stop = self.rules.cell_stop.tolist()
        self.ball_row = self.ball_col = self.ball_vx = self.paddle = 0
        self._terminated = True
        self._has_state = False
        self._window = None

    def get_action_meanings(self) -> list[str]:
        return list(ACTION_MEANINGS)

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        ball_col, ball_vx, paddle = self.rules.start_state(self.np_random.random(3))
        self._erase_ball()
        self.ball_row, self.ball_col, self.ball_vx = BALL_START_ROW, int(ball_col), int(ball_vx)
        self.paddle = int(paddle)
        self._draw()
        self._terminated, self._has_state = False, True
        if self.render_mode == "human":
            self.render()
        return self._canvas.copy(), {}

    def step(self, action: Any) -> tuple[np.ndarray, SupportsFloat, bool, bool, dict[str, Any]]:
        if type(action) is not int:
            integer_array = isinstance(action, np.ndarray) and action.dtype.kind in "iu"
            if not (isinstance(action, np.integer) or (integer_array and action.shape == ())):
                raise _action_error(action)
            action = int(action)
        if not 0 <= action < 3:
            raise _action_error(action)
        if self._terminated:
            raise RuntimeError(
                "Cannot step: the episode has ended (or never started). Call reset() first."
            )
        rules = self.rules
        self._erase_ball()
        self.ball_row += 1
        self.ball_col, self.ball_vx = rules.move_ball(self.ball_col, self.ball_vx)
        self.paddle = rules.move_paddle(self.paddle, ACTION_DIRECTION[action])
        self._draw()
        terminated = self.ball_row == rules.paddle_row
        reward = 1.0 if terminated and rules.caught(self.ball_col, self.paddle) else 0.0
        self._terminated = terminated
        if self.render_mode == "human":
            self.render()
        return self._canvas.copy(), reward, terminated, False, {}

    def _erase_ball(self) -> None:
        if self._has_state:
            start, stop = self._cell_start, self._cell_stop
            row, col = self.ball_row, self.ball_col
            self._canvas[start[row] : stop[row], start[col] : stop[col]] = OFF

    def _draw(self) -> None:
        start, stop = self._cell_start, self._cell_stop
        row, col, paddle_row = self.ball_row, self.ball_col, self.rules.paddle_row
        self._canvas[start[paddle_row] : stop[paddle_row]] = self.rules.paddle_line[self.paddle]
        self._canvas[start[row] : stop[row], start[col] : stop[col]] = ON

    def render(self) -> np.ndarray | None:
        if self.render_mode is None:
            gym.logger.warn(
                "Calling render() without a render_mode; make the env with "
                'render_mode="rgb_array" or "human".'
            )
            return None
        frame = np.repeat(self.rules.to_pixels(self._canvas)[:, :, None], 3, axis=2)
        if self.render_mode == "rgb_array":
            return frame
        if self._window is None:
            from catch_env.rendering import NoDisplayError, Window

            try:
                self._window = Window("Catch-v0", frame.shape[:2], zoom=6)
            except (NoDisplayError, ImportError) as error:  # like Gymnasium's: play on unseen
                gym.logger.warn(f'render_mode="human" shows nothing here: {error}')
                self._window = NO_WINDOW
        if self._window is not NO_WINDOW:
            self._window.show(frame, fps=self.metadata["render_fps"])
        return None

    def close(self) -> None:
        if self._window is not None and self._window is not NO_WINDOW:
            self._window.close()
        self._window = None

    def __getstate__(self) -> dict[str, Any]:
        # A pygame window cannot be pickled; the copy opens its own on the next render.
        state = self.__dict__.copy()
        state["_window"] = None
        return state


class CatchVectorEnv(VectorEnv):
    """N games of Catch stepped together with NumPy; the vector entry point of Catch-v0.

    `gym.make_vec("Catch-v0", num_envs=N)` builds it. It matches a `SyncVectorEnv` of N
    `CatchEnv`s exactly: the same seeds (an int seed s gives env i the seed s + i) and
    actions give the same observations, rewards, terminations and truncations. It uses
    Gymnasium's next-step autoreset: the step after an env terminates resets it, ignores
    its action and returns reward 0.

    `copy=True` (the default, as in `SyncVectorEnv`) returns fresh observation arrays;
    `copy=False` returns the env's own buffer, which the next step overwrites: faster,
    for callers that copy the observations themselves (as a training loop does when it
    writes them into its rollout storage). `infos` is always empty.
    """

    metadata = {"render_modes": ["rgb_array"], "autoreset_mode": AutoresetMode.NEXT_STEP}

    def __init__(
        self,
        num_envs: int = 1,
        grid_size: int = 24,
        paddle_width: int = 5,
        paddle_speed: int = 2,
        obs_type: Literal["pixels", "grid"] = "pixels",
        render_mode: str | None = None,
        copy: bool = True,
        start_buffer: int = START_BUFFER,
    ) -> None:
        self.num_envs = _check_int("num_envs", num_envs, 1, 2**24)
        self.rules = CatchRules(grid_size, paddle_width, paddle_speed, obs_type)
        self._start_buffer = _check_int("start_buffer", start_buffer, 1, 2**16)
        # before anything is allocated: an estimate beyond memory is one clear error, not an
        # allocation failure (or the swapping) half-way through
        per_env = VECTOR_FRAMES_PER_ENV * self.rules.obs_side**2 + self._start_buffer * 3 * 8
        needed, available = self.num_envs * per_env, available_memory()
        if available is not None and needed > available:
            raise MemoryError(
                f"num_envs={self.num_envs} needs about {format_bytes(needed)} "
                f"({format_bytes(per_env)} per env), more than the "
                f"{format_bytes(available)} of memory available"
            )
        if render_mode not in (None, "rgb_array"):
            raise ValueError(f"render_mode must be None or 'rgb_array', got {render_mode!r}")
        self.render_mode = render_mode
        self.copy = copy
        self.single_observation_space = self.rules.observation_space()
        self.single_action_space = spaces.Discrete(len(ACTION_MEANINGS))
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self.action_space = batch_space(self.single_action_space, self.num_envs)

        n = self.num_envs
        self._obs = np.zeros((n, *self.single_observation_space.shape), dtype=np.uint8)
        # The rules tabulated over every (column, speed) and (centre, action), so a step of
        # N games is two table look-ups.
        size, speeds = self.rules.grid_size, 2 * MAX_BALL_SPEED + 1
        next_col, next_vx = self.rules.move_ball(
            np.arange(size)[:, None], np.arange(-MAX_BALL_SPEED, MAX_BALL_SPEED + 1)[None, :]
        )
        self._next_ball_col, self._next_ball_vx = next_col.ravel(), next_vx.ravel()
        self._speeds = speeds
        next_paddle = self.rules.move_paddle(
            np.arange(size)[:, None], np.array(ACTION_DIRECTION)[None, :]
        )
        self._next_paddle = next_paddle.ravel()
        # Flat offset of each game's canvas, and the canvas offsets drawn at the last step.
        self._canvas_base = np.arange(n)[:, None] * self._obs[0].size
        self._drawn: tuple[np.ndarray, np.ndarray] | None = None
        self.ball_row = np.full(n, BALL_START_ROW)
        self.ball_col = np.zeros(n, dtype=np.int64)
        self.ball_vx = np.zeros(n, dtype=np.int64)
        self.paddle = np.zeros(n, dtype=np.int64)
        self._needs_reset = np.ones(n, dtype=bool)
        # One generator per env, as in N single envs. Start states are drawn `start_buffer`
        # games at a time per env, in one call, to keep the per-env Python loop rare.
        self._rngs = [seeding.np_random()[0] for _ in range(n)]
        self._starts = np.zeros((n, self._start_buffer, 3))
        self._starts_used = np.full(n, self._start_buffer)

    def get_action_meanings(self) -> list[str]:
        return list(ACTION_MEANINGS)

    def get_state(self) -> dict[str, Any]:
        """Everything a step depends on that the constructor does not fix, as NumPy arrays and
        each generator's `bit_generator.state` (plain numbers): a copy, for `set_state`. The
        canvas is not in it: `set_state` draws it from the balls and paddles."""
        if self._drawn is None:
            raise RuntimeError("Cannot get the state before reset(): call reset() first.")
        arrays = {name: getattr(self, name).copy() for name in self._STATE_ARRAYS}
        return {**arrays, "rngs": [rng.bit_generator.state for rng in self._rngs]}

    def set_state(self, state: dict[str, Any]) -> None:
        """Go on from `get_state()`'s copy, taken from an env made with the same arguments; a
        state of another shape is a ValueError and leaves this env as it was."""
        arrays = {name: np.asarray(state[name]) for name in self._STATE_ARRAYS}
        for name, array in arrays.items():
            own = getattr(self, name)
            if array.shape != own.shape:
                raise ValueError(f"state {name!r} has shape {array.shape}, not {own.shape}")
        if len(state["rngs"]) != self.num_envs:
            raise ValueError(f"state is not that of {self.num_envs} envs")
        rngs = [np.random.Generator(np.random.PCG64()) for _ in range(self.num_envs)]
        for rng, rng_state in zip(rngs, state["rngs"], strict=True):
            rng.bit_generator.state = rng_state
        for name, array in arrays.items():
            setattr(self, name, array.astype(getattr(self, name).dtype, copy=True))
        self._rngs = rngs
        self._redraw()

    _STATE_ARRAYS = ("ball_row", "ball_col", "ball_vx", "paddle", "_needs_reset", "_starts",
                     "_starts_used")  # fmt: skip

    def reset(
        self, *, seed: int | list[int | None] | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        if seed is not None:
            self._rngs = [seeding.np_random(s)[0] for s in vector_seeds(seed, self.num_envs)]
            self._starts_used[:] = self._start_buffer
        mask = np.ones(self.num_envs, dtype=bool)
        if options is not None and "reset_mask" in options:
            mask = np.asarray(options["reset_mask"], dtype=bool)
            if mask.shape != (self.num_envs,):
                raise ValueError(f"reset_mask must have shape ({self.num_envs},), got {mask.shape}")
        self._start_games(np.flatnonzero(mask))
        self._redraw()
        self._needs_reset &= ~mask
        return self._observations(), {}

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        actions = np.asarray(actions)
        if actions.shape != (self.num_envs,) or actions.dtype.kind not in "iu":
            raise ValueError(
                f"actions must be an integer array of shape ({self.num_envs},) with values "
                f"{_VALID_ACTIONS}; got {actions.dtype} array of shape {actions.shape}"
            )
        if actions.size and (actions.min() < 0 or actions.max() >= 3):
            raise _action_error(actions)
        if self._drawn is None:
            raise RuntimeError("Cannot step before reset(): call reset() first.")
        ball = self.ball_col * self._speeds + (self.ball_vx + MAX_BALL_SPEED)
        self.ball_row += 1
        self.ball_col, self.ball_vx = self._next_ball_col[ball], self._next_ball_vx[ball]
        self.paddle = self._next_paddle[self.paddle * len(ACTION_MEANINGS) + actions]
        resetting = self._needs_reset
        if resetting.any():
            self._start_games(np.flatnonzero(resetting))
        self._redraw()
        terminated = self.ball_row == self.rules.paddle_row
        rewards = np.zeros(self.num_envs, dtype=np.float32)
        if terminated.any():  # one step in 15: skip the reward arithmetic on the others
            rewards[terminated & self.rules.caught(self.ball_col, self.paddle)] = 1.0
        self._needs_reset = terminated
        truncated = np.zeros(self.num_envs, dtype=bool)
        return self._observations(), rewards, terminated.copy(), truncated, {}

    def _start_games(self, envs: np.ndarray) -> None:
        if envs.size == 0:
            return
        for env in envs[self._starts_used[envs] == self._start_buffer]:
            self._starts[env] = self._rngs[env].random((self._start_buffer, 3))
            self._starts_used[env] = 0
        uniforms = self._starts[envs, self._starts_used[envs]]
        self._starts_used[envs] += 1
        self.ball_col[envs], self.ball_vx[envs], self.paddle[envs] = self.rules.start_state(
            uniforms
        )
        self.ball_row[envs] = BALL_START_ROW

    def _redraw(self) -> None:
        """Erase what the last step drew and draw every game's ball and paddle."""
        canvas = self._obs.reshape(-1)
        for drawn in self._drawn or ():
            canvas[drawn] = OFF
        rules = self.rules
        # np.take is several times faster than fancy indexing for gathering rows.
        ball = np.take(rules.ball_sprite, self.ball_row * rules.grid_size + self.ball_col, axis=0)
        paddle = np.take(rules.paddle_sprite, self.paddle, axis=0)
        self._drawn = (self._canvas_base + ball, self._canvas_base + paddle)
        for drawn in self._drawn:
            canvas[drawn] = ON

    def _observations(self) -> np.ndarray:
        return self._obs.copy() if self.copy else self._obs

    def render(self) -> tuple[np.ndarray, ...] | None:
        if self.render_mode != "rgb_array":
            return None
        frames = np.repeat(self.rules.to_pixels(self._obs)[..., None], 3, axis=-1)
        return tuple(frames)
