"""Catch-v0 and the thesis's preprocessing, for Gymnasium.

Importing this package registers `Catch-v0` (Gymnasium 1.x has no plugin entry points),
so `gymnasium.make("catch_env:Catch-v0")` works from a fresh interpreter, and
`gymnasium.make_vec("Catch-v0", num_envs=N)` gives the NumPy-batched `CatchVectorEnv`.
"""

import gymnasium as gym

from catch_env.catch import ACTION_MEANINGS, CatchEnv, CatchRules, CatchVectorEnv

__all__ = ["ACTION_MEANINGS", "CATCH_ENTRY_POINT", "CatchEnv", "CatchRules", "CatchVectorEnv"]
__version__ = "0.1.0"
CATCH_ENTRY_POINT = "catch_env.catch:CatchEnv"

if "Catch-v0" not in gym.registry:
    gym.register(
        id="Catch-v0",
        entry_point=CATCH_ENTRY_POINT,
        vector_entry_point="catch_env.catch:CatchVectorEnv",
    )
