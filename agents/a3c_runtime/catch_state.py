"""A worker's Catch games in a checkpoint: the arrays of their state (catch_env's vector env
under its frame stacks, `get_state()`, its generators apart) by flat name, with their dtypes and
shapes (`catch_layout`), and the values those arrays take between two steps (`catch_problem`):
a hand-edited ball off the board, a start draw of 2 or a canvas that is not the games' is
refused (a3c_runtime.checkpoint_file, before anything reaches an env)."""

import functools
from typing import Any

import torch


@functools.cache
def catch_layout() -> dict[str, tuple[torch.dtype, tuple[int, ...]]]:
    """The arrays of a Catch vector env's state (catch_env.wrappers' get_state, its generators
    apart) by path, with their dtypes and their shapes after the leading one (the env count)."""
    from catch_env.wrappers import make_vector_env

    envs = make_vector_env("Catch-v0", 1)
    envs.reset(seed=0)
    layout, todo = {}, [("", envs.get_state())]
    while todo:
        path, value = todo.pop()
        if isinstance(value, dict):
            todo += [(f"{path}{k}/", v) for k, v in value.items() if k != "rngs"]
        elif isinstance(value, list):
            todo += [(f"{path}{i}/", v) for i, v in enumerate(value)]
        else:
            layout[path[:-1]] = (torch.from_numpy(value).dtype, value.shape[1:])
    return dict(sorted(layout.items()))


def part_at(state: dict, path: str) -> Any:
    """The array at a catch_layout path of a state in get_state's nested form."""
    for key in path.split("/"):
        state = state[int(key) if isinstance(state, list) else key]
    return state


@functools.cache
def catch_rules() -> tuple[Any, dict[str, tuple[float, float]], tuple[torch.Tensor, ...]]:
    """The rules of the Catch games the scripts make, the inclusive bounds of their arrays
    between two steps (an ended game starts again in the same step; start draws in [0, 1)), and
    the canvas cells of a ball at each cell and of a paddle at each column."""
    from catch_env.catch import BALL_START_ROW, MAX_BALL_SPEED, CatchRules

    rules, last = CatchRules(), CatchRules().episode_length - 1
    bounds = {"env/ball_row": (BALL_START_ROW, BALL_START_ROW + last), "lengths": (0, last),
              "env/ball_col": (0, rules.grid_size - 1), "env/paddle": (rules.paddle_min,
              rules.paddle_max), "env/ball_vx": (-MAX_BALL_SPEED, MAX_BALL_SPEED),
              "env/_needs_reset": (0, 0), "returns": (0, 1), "env/_starts": (0, 1 - 2**-53),
              "env/_starts_used": (0, catch_layout()["env/_starts"][1][0])}  # fmt: skip
    return rules, bounds, (torch.tensor(rules.ball_sprite), torch.tensor(rules.paddle_sprite))


def catch_problem(state: dict[str, torch.Tensor], frames: torch.Tensor) -> str | None:
    """What of a worker's Catch games (their arrays by catch_layout's names, of its dtypes and
    shapes) is no state they reach between steps, or None: each value within its bounds, the
    canvas, the cells drawn on it and the last frame of each stack those of the games'
    positions, the stacks' pixels 0 or 255, and the frames the worker acts on its stacks."""
    rules, bounds, (ball, paddle) = catch_rules()
    for name, (low, high) in bounds.items():
        outside = (state[name] < low) | (state[name] > high)
        if bool(outside.any()):
            value = state[name][outside][0].item()
            return f"{name} holds {value} (valid: {low:g} to {high:.3g})"
    n, side = len(frames), rules.obs_side
    base = torch.arange(n)[:, None] * side * side
    cell = state["env/ball_row"] * rules.grid_size + state["env/ball_col"]
    drawn = (ball[cell] + base, paddle[state["env/paddle"]] + base)
    canvas = torch.zeros(n * side * side, dtype=torch.uint8)
    canvas[torch.cat([d.flatten() for d in drawn])] = 255
    if not all(torch.equal(state[f"env/drawn/{i}"], drawn[i]) for i in range(2)):
        return "env/drawn is not the cells of the balls and paddles"
    if not torch.equal(state["env/_obs"], canvas.view(n, side, side)):
        return "env/_obs is not the canvas of the balls and paddles"
    if not torch.equal(state["stack"][:, -1], state["env/_obs"]):
        return "stack's last frames are not the canvas"
    if not bool(((state["stack"] == 0) | (state["stack"] == 255)).all()):
        return "stack holds a pixel that is neither 0 nor 255"
    return None if torch.equal(frames, state["stack"]) else "frames are not the envs' stacks"
