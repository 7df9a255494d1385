"""Play Catch-v0 with a uniformly random policy and print how often it catches the ball.

    python examples/random_agent.py                 # 1000 episodes, no window
    python examples/random_agent.py --render -n 5   # watch 5 episodes in a pygame window

A random paddle catches about one ball in five: the baseline a learner has to beat.
"""

from __future__ import annotations

import argparse

import gymnasium as gym

import catch_env  # noqa: F401  (registers Catch-v0)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-n", "--episodes", type=int, default=1000, help="episodes to play")
    parser.add_argument("--seed", type=int, default=0, help="seed of the env and the policy")
    parser.add_argument("--render", action="store_true", help="show the game in a window")
    args = parser.parse_args()
    if args.episodes < 1:
        parser.error(f"--episodes must be positive, got {args.episodes}")

    env = gym.make("Catch-v0", render_mode="human" if args.render else None)
    # Seeding the action space too makes the whole run reproducible.
    env.action_space.seed(args.seed)
    catches = 0
    for episode in range(args.episodes):
        # Seed only the first reset; later resets continue the same random stream.
        env.reset(seed=args.seed if episode == 0 else None)
        terminated = truncated = False
        while not (terminated or truncated):
            action = env.action_space.sample()
            _, reward, terminated, truncated, _ = env.step(action)
            # Catch pays 1 on the last step if the paddle is under the ball, else 0.
            catches += int(reward)
    env.close()
    print(f"{catches}/{args.episodes} balls caught: catch rate {catches / args.episodes:.3f}")


if __name__ == "__main__":
    main()
