"""Step many Catch games at once with `gymnasium.make_vec`, counting episodes correctly.

    python examples/vector_env.py --num-envs 256 --steps 2000

`make_vec("Catch-v0", num_envs=N)` builds `CatchVectorEnv`, which steps all N games with
NumPy. It uses Gymnasium's next-step autoreset: when game i ends at step t, step t + 1
does not play; it resets game i, ignores its action, and returns its first observation
with reward 0 and terminated False. So that step is not a transition of the game: it is
left out of the step count here (and a learner must not store it as one).
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np

import catch_env  # noqa: F401  (registers Catch-v0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--num-envs", type=int, default=64, help="games stepped together")
    parser.add_argument("--steps", type=int, default=1000, help="vector steps to take")
    parser.add_argument("--seed", type=int, default=0, help="seed of the envs and the policy")
    args = parser.parse_args()
    if args.num_envs < 1 or args.steps < 1:
        parser.error("--num-envs and --steps must be positive")

    envs = gym.make_vec("Catch-v0", num_envs=args.num_envs)
    envs.action_space.seed(args.seed)
    envs.reset(seed=args.seed)
    # Which games the next step will reset instead of play (none right after reset()).
    autoreset = np.zeros(args.num_envs, dtype=bool)
    episodes = catches = game_steps = 0

    start = time.perf_counter()
    for _ in range(args.steps):
        actions = envs.action_space.sample()
        _, rewards, terminated, truncated, _ = envs.step(actions)
        played = ~autoreset
        game_steps += int(played.sum())
        ended = (terminated | truncated) & played
        episodes += int(ended.sum())
        # Rewards of reset steps are 0 by the convention above; masking says so explicitly.
        catches += int(rewards[ended].sum())
        autoreset = terminated | truncated
    elapsed = time.perf_counter() - start
    envs.close()

    rate = catches / episodes if episodes else float("nan")
    print(
        f"{args.num_envs} envs x {args.steps} steps: {episodes} episodes, {catches} catches "
        f"(catch rate {rate:.3f}), {game_steps} game steps"
    )
    print(f"{args.num_envs * args.steps / elapsed:,.0f} env steps/s ({elapsed:.2f} s)")


if __name__ == "__main__":
    main()
