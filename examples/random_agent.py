"""Play a game with a uniformly random policy: the baseline a learner has to beat.

    python examples/random_agent.py                 # Catch-v0, 1000 episodes, no window
    python examples/random_agent.py --render -n 5   # watch 5 episodes in a pygame window
    python examples/random_agent.py --env BreakoutNoFrameskip-v4 -n 50   # an Atari game

On Catch-v0 a random paddle catches about one ball in five. An ALE id is played through the
agents' preprocessing (catch_env.wrappers.make_env: action repeat 4, no-op starts, FIRE on
reset) and the raw game score of each episode is reported, as the agents' evaluations do.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import catch_env  # noqa: F401  (registers Catch-v0)
from catch_env.wrappers import make_env


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-n", "--episodes", type=int, default=1000, help="episodes to play")
    parser.add_argument("--seed", type=int, default=0, help="seed of the env and the policy")
    parser.add_argument("--render", action="store_true", help="show the game in a window")
    parser.add_argument("--env", default="Catch-v0", help="Catch-v0 or an ALE id")
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error(f"--episodes must be positive, got {args.episodes}")

    render_mode = "human" if args.render else None
    try:
        if args.env == "Catch-v0":
            env = gym.make("Catch-v0", render_mode=render_mode)
        else:
            env = make_env(args.env, render_mode=render_mode)
    except (gym.error.Error, ImportError, ValueError) as e:
        parser.error(f"--env {args.env!r}: {e} (valid: Catch-v0 or an ALE id)")
    # Seeding the action space too makes the whole run reproducible.
    env.action_space.seed(args.seed)
    scores = []
    for episode in range(args.episodes):
        # Seed only the first reset; later resets continue the same random stream.
        env.reset(seed=args.seed if episode == 0 else None)
        terminated = truncated = False
        score = 0.0
        while not (terminated or truncated):
            action = env.action_space.sample()
            _, reward, terminated, truncated, info = env.step(action)
            score += float(reward)
        # the wrappers clip Atari rewards; info["episode"] holds the raw game score
        scores.append(float(info["episode"]["r"]) if "episode" in info else score)
    env.close()
    if args.env == "Catch-v0":
        # Catch pays 1 on the last step if the paddle is under the ball, else 0.
        catches = int(sum(scores))
        print(f"{catches}/{args.episodes} balls caught: catch rate {catches / args.episodes:.3f}")
    else:
        print(f"{args.env}: mean score {np.mean(scores):.2f} +- {np.std(scores):.2f} over "
              f"{args.episodes} episodes of random play")  # fmt: skip


if __name__ == "__main__":
    main()
