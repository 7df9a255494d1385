"""A worker's Catch games in a checkpoint (catch_env's vector env under its frame stacks, as
`get_state()` gives it): their positions and episode sums in the document, typed and bounded by
`CatchGames` (a ball off the board or a start draw used past the buffer is no state the games
reach, and the schema refuses it); their generators, start draws and the stacks' older frames
(as bits: a pixel is on or off) as tensors. The canvas and each stack's newest frame are not
stored: they are drawn from the positions on load, so a file cannot make them disagree. And a
generator's state as a checkpoint holds any generator (a worker's too): its 37 bytes, every
value of which is a PCG64 state (`generator_bytes`)."""

import functools
from typing import Annotated, Any

import torch
from pydantic import BaseModel, ConfigDict, Field

from catch_env.catch import BALL_START_ROW, MAX_BALL_SPEED, START_BUFFER, CatchRules

MAX_ENVS = 4096
RULES = CatchRules()  # the games the scripts make
LAST = RULES.episode_length - 1  # an ended game starts again in the same step


class Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True, allow_inf_nan=False, frozen=True)


PCG64_BYTES = 37  # its 128-bit state and increment, has_uint32 (a byte), uinteger (4 bytes)


def per_env(low: float, high: float, kind: type = int) -> Any:
    """A list of one value per env, each within [low, high]."""
    return Annotated[list[Annotated[kind, Field(ge=low, le=high)]], Field(max_length=MAX_ENVS)]


class CatchGames(Strict):
    """A worker's Catch games between two steps, one value per env (none awaits a reset)."""

    ball_row: per_env(BALL_START_ROW, BALL_START_ROW + LAST)
    ball_col: per_env(0, RULES.grid_size - 1)
    ball_vx: per_env(-MAX_BALL_SPEED, MAX_BALL_SPEED)
    paddle: per_env(RULES.paddle_min, RULES.paddle_max)
    starts_used: per_env(0, START_BUFFER)  # (the starts tensor's rows used)
    lengths: per_env(0, LAST)
    returns: per_env(0, 1, float)


POSITIONS = ("ball_row", "ball_col", "ball_vx", "paddle")


def generator_bytes(state: dict) -> torch.Tensor:
    """A NumPy PCG64 generator's `bit_generator.state` as a checkpoint holds it: PCG64_BYTES
    bytes, little-endian, every value of which is a PCG64 state (so none needs a check).
    ValueError (OverflowError) for another generator or a state no PCG64 has."""
    if state["bit_generator"] != "PCG64":
        raise ValueError(f"a {state['bit_generator']} generator is not a PCG64 one")
    words = state["state"]
    data = (words["state"].to_bytes(16, "little") + words["inc"].to_bytes(16, "little")
            + bytes([state["has_uint32"]]) + state["uinteger"].to_bytes(4, "little"))  # fmt: skip
    return torch.frombuffer(bytearray(data), dtype=torch.uint8)


def generator_state(stored: torch.Tensor) -> dict:
    """generator_bytes reversed: NumPy's `bit_generator.state`."""
    data = bytes(stored.tolist())
    word = functools.partial(int.from_bytes, byteorder="little")
    return {"bit_generator": "PCG64", "state": {"state": word(data[:16]), "inc": word(data[16:32])},
            "has_uint32": data[32] & 1, "uinteger": word(data[33:])}  # fmt: skip


def stored_games(state: dict, frames: torch.Tensor) -> tuple[dict, dict[str, torch.Tensor]]:
    """(the document's CatchGames, the tensors by name) of a worker's Catch envs' `get_state()`
    (as tensors) and the frames it acts on (its envs' stacks)."""
    inner = state["env"]
    games = {**{name: inner[name].tolist() for name in POSITIONS},
             "starts_used": inner["_starts_used"].tolist(), "lengths": state["lengths"].tolist(),
             "returns": state["returns"].tolist()}  # fmt: skip
    generators = torch.stack([generator_bytes(state) for state in inner["rngs"]])
    return games, {"starts": inner["_starts"], "frames": frames[:, :-1] == 255,
                   "generators": generators}  # fmt: skip


def loaded_games(games: dict, tensors: dict[str, torch.Tensor]) -> tuple[dict, torch.Tensor]:
    """stored_games reversed: (the envs' `get_state()`, the frames), the canvas and each stack's
    newest frame drawn from the balls and paddles as the env draws them."""
    n, side = len(games["ball_row"]), RULES.obs_side
    cells = torch.tensor(games["ball_row"]) * RULES.grid_size + torch.tensor(games["ball_col"])
    ball, paddle = torch.tensor(RULES.ball_sprite), torch.tensor(RULES.paddle_sprite)
    drawn = torch.cat([ball[cells], paddle[torch.tensor(games["paddle"])]], 1)
    newest = torch.zeros(n, side * side, dtype=torch.uint8).scatter_(1, drawn, 255)
    frames = torch.cat([tensors["frames"].to(torch.uint8) * 255, newest.view(n, 1, side, side)], 1)
    inner = {name: torch.tensor(games[name]) for name in POSITIONS}
    inner.update(_needs_reset=torch.zeros(n, dtype=torch.bool), _starts=tensors["starts"],
                 _starts_used=torch.tensor(games["starts_used"]),
                 rngs=[generator_state(s) for s in tensors["generators"]])  # fmt: skip
    lengths = torch.tensor(games["lengths"])
    returns = torch.tensor(games["returns"], dtype=torch.float64)
    return {"stack": frames.clone(), "returns": returns, "lengths": lengths, "env": inner}, frames
