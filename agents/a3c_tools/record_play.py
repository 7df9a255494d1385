"""A trained agent playing, as an animated GIF for the docs: one episode of a checkpoint's
network on the game it was trained on, drawn from the game's own screen (the ALE's 210x160
frames, Catch's 84x84), the actions sampled from pi by the evaluations' own loop
(a3c_runtime.play_episodes).

    python -m a3c_tools.record_play results/breakout_a3c_ff/checkpoint.pt \\
        -o docs/img/breakout_a3c_ff.gif --seed 1 --speed 2

It plays the whole episode (so the score it prints is the game's), then writes it, or its first
--seconds, at --speed times the game's own speed (Atari: 60 frames/s of which the agent sees
every 4th, so 15 screens per second; Catch: 10 steps per second), every --speed-th screen
shown. The checkpoint names the script that wrote it;
that script builds the env and the network. Pillow (the `tools` extra, through matplotlib)
writes the GIF.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

import numpy as np
import torch

from a3c_tools import AGENTS, agent_scripts, load_script, run_main, tool_parser

FRAMES_PER_SECOND = {"catch": 10, "atari": 15}  # Catch has no clock; ALE: 60 Hz / frameskip 4


def checked_checkpoint(path: str) -> tuple[Any, Any]:
    """(its script's Agent, the checkpoint) of a checkpoint through the gate
    (a3c_runtime.checkpoints.open_checkpoint, then for_agent), its script one of this clone's
    agent scripts (agents/, agents/future_work/), imported only then; a bad file is refused in
    one line."""
    from a3c_runtime import UsageError
    from a3c_runtime.checkpoints import for_agent, open_checkpoint

    checkpoint = open_checkpoint(path)
    if checkpoint.script not in agent_scripts():
        raise UsageError(f"{path!r} does not name an agent script that wrote it")
    agent = load_script(AGENTS / checkpoint.script).AGENT
    return agent, for_agent(checkpoint, agent)


def play_recorded(
    path: str, seed: int, greedy: bool = False
) -> tuple[list[np.ndarray], float, str]:
    """One episode of the checkpoint's network: the screen before each action and after the
    last, the episode's raw score and the env id."""
    import gymnasium as gym
    from a3c_runtime import play_episodes
    from a3c_runtime.checkpoints import load_network
    from a3c_runtime.flags import probe_env

    import catch_env  # noqa: F401  (registers Catch-v0)

    agent, checkpoint = checked_checkpoint(path)
    trained = checkpoint.flags
    model = agent.network(probe_env(agent.make_env, checkpoint.env), trained)
    load_network(model, checkpoint)
    if hasattr(model, "set_progress"):  # e.g. GLPQ's temperature schedule
        model.set_progress(checkpoint.global_step / trained.total_timesteps)
    # the evaluation's own episode loop; the wrapper keeps the screen after reset and each step
    env = gym.wrappers.RenderCollection(agent.make_env(checkpoint.env, render_mode="rgb_array"))
    generator = torch.Generator().manual_seed(seed)
    score = play_episodes(model, [env], [seed], greedy=greedy, generator=generator)[0]
    frames = env.render()
    env.close()
    return frames, float(score), checkpoint.env


def write_gif(frames: list[np.ndarray], out: Path, fps: int, scale: int = 1) -> None:
    """An animated GIF, looping, at fps as near as a GIF can (its durations are whole 10 ms,
    and Pillow truncates: 1000 / 15 would be stored as 60 ms)."""
    from PIL import Image

    images = [Image.fromarray(np.asarray(frame, dtype=np.uint8)) for frame in frames]
    if scale > 1:
        images = [i.resize((i.width * scale, i.height * scale), Image.NEAREST) for i in images]
    out.parent.mkdir(parents=True, exist_ok=True)
    images[0].save(
        out, save_all=True, append_images=images[1:], duration=10 * round(100 / fps), loop=0,
        optimize=True,
    )  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    parser = tool_parser("record_play", __doc__.split("\n\n")[0])
    parser.add_argument("checkpoint", help="a checkpoint.pt written by an agent script")
    parser.add_argument("-o", "--out", type=Path, required=True, help="the GIF to write")
    parser.add_argument("--seed", type=int, default=1, help="of the episode and its actions")
    parser.add_argument("--seconds", type=float, help="of the GIF (default: the whole episode)")
    parser.add_argument("--speed", type=int, default=1, help="times the game's speed")
    parser.add_argument("--scale", type=int, default=1, help="pixels per screen pixel")
    parser.add_argument("--greedy", action="store_true", help="argmax pi, not a sample")
    args = parser.parse_args(argv)
    from a3c_runtime import UsageError

    try:
        if (args.seconds is not None and args.seconds <= 0) or args.scale < 1 or args.speed < 1:
            raise UsageError("--seconds must be > 0, --scale and --speed >= 1")
        if args.out.suffix.lower() != ".gif":
            raise UsageError(f"--out must end in .gif (got {str(args.out)!r})")
        frames, score, env_id = play_recorded(args.checkpoint, args.seed, args.greedy)
    except UsageError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    fps = FRAMES_PER_SECOND["catch" if env_id.startswith("Catch") else "atari"]
    shown = frames[:: args.speed]
    if args.seconds is not None:
        shown = shown[: max(1, round(args.seconds * fps))]
    write_gif(shown, args.out, fps, args.scale)
    print(
        f"{args.out}: {len(shown)} of the episode's {len(frames)} screens ({len(shown) / fps:.0f} "
        f"s at {fps}/s, {args.speed}x the game's speed); the episode scored {score:g} "
        f"(seed {args.seed})"
    )
    return 0


if __name__ == "__main__":
    run_main(main)
