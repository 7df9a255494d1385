"""Every agent script's worker loop (Algorithm 1) in process, at K = 1 and K = 4 envs per worker
and in each --precision: it takes the steps and updates it should, every parameter learns (but
those listed in NO_GRADIENT, with the reason), the weights and optimizer statistics stay finite
float32, it prints no warnings and keeps no autograd history."""

import math
import warnings

import a3c_runtime as runtime
import gymnasium as gym
import numpy as np
import pytest
import torch
from conftest import ALL_SCRIPTS, SCRIPTS, load_script, shared_for, tiny_args

import catch_env  # noqa: F401  (registers Catch-v0)


def no_gradient(name: str, model: torch.nn.Module, k: int) -> dict[str, torch.Tensor]:
    """The parameter entries that provably get no gradient, as a mask per parameter (True: may
    stay unchanged). One list for every script, K and precision:
    - a3c_ss: the second convolution's bias (torso.2.bias) adds a constant to each map, which the
      spatial softmax over the map's positions ignores;
    - a3c_ww: for the same reason, the biases of its "where" maps, the second convolution's
      channels from what_maps on (convs.2.bias[what_maps:]); its "what" biases must learn;
    - the growth scripts: the slot mask (prototype_active), used detached and written only by the
      growth step, and the free slots' prototypes, which take no part in the policy;
    - a3c_lws_online at K = 1: the centroid predictor's encoder gets its gradient through the
      heads, whose weights start at 0 (so that the predicted centroids start at the static ones),
      so over the K = 1 case's small updates its steps stay below float32's resolution of its
      weights; it learns in the K = 4 case.
    (Such a gradient is zero up to rounding, so these may change a little: they are not checked.)
    """
    params = dict(model.named_parameters())
    exempt = {}
    if name == "a3c_ss":
        exempt["torso.2.bias"] = torch.ones_like(params["torso.2.bias"], dtype=torch.bool)
    if name == "a3c_ww":
        mask = torch.zeros_like(params["convs.2.bias"], dtype=torch.bool)
        mask[model.what_maps :] = True
        exempt["convs.2.bias"] = mask
    if name.endswith("_growth"):
        exempt["prototype_active"] = torch.ones_like(params["prototype_active"], dtype=torch.bool)
        free = ~model.active_slots().flatten()
        exempt["prototypes"] = free[:, None].expand_as(params["prototypes"])
    if name == "a3c_lws_online" and k == 1:
        for key, param in params.items():
            if key.startswith("centroid_predictor.encoder."):
                exempt[key] = torch.ones_like(param, dtype=torch.bool)
    return exempt


# (K, t_max, T_max): K = 1 with t_max 5 < Catch's 15-step episodes, so rollouts bootstrap from
# V(s_last), for 10 episodes (a value head whose values start at 0 learns only from a return
# that is not 0: a catch); K = 4 with t_max 20, so the 4 episodes end together after 15 steps
# and each update holds 4 x 15 states
SETTINGS = {1: (5, 150), 4: (20, 120)}
# each thesis script in fp32 (--precision auto at K = 1, and without native bf16) and in bf16:
# bf16-learn at K = 1 (one flag away), bf16 at K > 1 (auto with native bf16); chapter 8's in fp32
PRECISIONS = {1: ("fp32", "bf16-learn"), 4: ("fp32", "bf16")}
CASES = [
    (name, k, precision)
    for name in ALL_SCRIPTS
    for k in SETTINGS
    for precision in (PRECISIONS[k] if name in SCRIPTS else ("fp32",))
]


@pytest.mark.parametrize(("name", "k", "precision"), CASES)
def test_every_parameter_learns(name, k, precision, one_thread):
    module = load_script(name)
    t_max, steps = SETTINGS[k]
    args = tiny_args(
        module, total_timesteps=steps, t_max=t_max, envs_per_worker=k, precision=precision
    )
    torch.manual_seed(0)  # the network's initialisation; the worker seeds its own streams
    shared = shared_for(module, args)
    before = {key: p.detach().clone() for key, p in shared.model.named_parameters()}
    exempt = no_gradient(name, shared.model, k)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # normal runs print no warnings
        module.worker(0, shared, args)
    stats = dict(zip(shared.STATS, shared.stats[0].tolist(), strict=True))
    if k == 1:
        assert steps <= shared.global_step() < steps + t_max
        assert stats["updates"] >= steps // t_max
    else:
        assert shared.global_step() == steps
        assert (stats["updates"], stats["episodes"], stats["length_sum"]) == (2, 8, 8 * 15)
    for key, new in shared.model.named_parameters():
        new = new.detach()
        assert new.dtype == torch.float32 and torch.isfinite(new).all(), key
        learnt = new != before[key]
        if key in exempt:
            learnt = learnt | exempt[key]
        assert learnt.any(), f"{key} did not learn"
        must_learn = ~exempt[key] if key in exempt else None
        if must_learn is not None and must_learn.any():
            assert (new != before[key])[must_learn].any(), f"{key} (its learning part) is fixed"
    for statistics in shared.optimizer.state_dict().values():
        for statistic in statistics if isinstance(statistics, list) else [statistics]:
            assert statistic.dtype in (torch.float32, torch.float64), statistic.dtype
            assert torch.isfinite(statistic).all()
    # logging the losses must not chain each rollout's graph onto the stats (a memory leak)
    assert shared.stats.grad_fn is None and not shared.stats.requires_grad
    assert all(torch.isfinite(torch.tensor(v)) for v in stats.values())


# --- The worker's rollouts against a scripted env ----------------------------------------------


class ScriptedVectorEnv:
    """make_vector_env's contract (same-step autoreset, final_obs and final_info of ended
    episodes) for K envs whose episodes last lengths[k] steps and end in a terminal state or,
    where truncates[k], a time limit. Each frame is one random grey level (so that V differs
    from state to state), rewards are random; it records every frame and step."""

    def __init__(self, lengths: list[int], truncates: list[bool]):
        self.num_envs = len(lengths)
        self.lengths, self.truncates = np.array(lengths), np.array(truncates)
        self.single_observation_space = gym.spaces.Box(0, 255, (4, 84, 84), np.uint8)
        self.single_action_space = gym.spaces.Discrete(3)
        self.rng = np.random.default_rng(0)
        self.frames: list[np.ndarray] = []  # (K, 4, 84, 84): the reset's, then each step's
        self.steps: list[dict] = []

    def frame(self, envs: int) -> np.ndarray:
        levels = self.rng.integers(0, 256, envs).astype(np.uint8)
        return np.broadcast_to(levels[:, None, None, None], (envs, 4, 84, 84)).copy()

    def reset(self, seed: int | None = None):
        self.t = np.zeros(self.num_envs, dtype=np.int64)
        self.frames.append(self.frame(self.num_envs))
        return self.frames[-1].copy(), {}

    def step(self, actions):
        self.t += 1
        ended = self.t == self.lengths
        terminated, truncated = ended & ~self.truncates, ended & self.truncates
        rewards = self.rng.integers(-2, 3, self.num_envs).astype(np.float32)
        final_obs = np.full(self.num_envs, None, dtype=object)
        for i in np.flatnonzero(ended):
            final_obs[i] = self.frame(1)[0]
        self.frames.append(self.frame(self.num_envs))
        self.steps.append(
            {"actions": np.array(actions), "rewards": rewards, "terminated": terminated,
             "truncated": truncated, "final_obs": final_obs}
        )  # fmt: skip
        info = {}
        if ended.any():
            episode = {"r": rewards.astype(np.float64), "l": self.t.copy()}
            info = {"final_obs": final_obs, "_final_obs": ended.copy(),
                    "final_info": {"episode": episode, "_episode": ended.copy()},
                    "_final_info": ended.copy()}  # fmt: skip
            self.t[ended] = 0
        return self.frames[-1].copy(), rewards, terminated, truncated, info

    def close(self) -> None:
        pass


def scripted_run(module, monkeypatch, env: ScriptedVectorEnv, **flags):
    """Run the script's worker on env with a learning rate of 0 (the network stays the initial
    one); returns the shared network and each update's a3c_loss arguments."""
    monkeypatch.setattr(module, "make_vector_env", lambda env_id, num_envs, life_loss: env)
    updates = []

    def recorded_loss(log_probs, actions, values, returns, ent_coef, vf_coef, value_loss_form):
        updates.append({"log_probs": log_probs.detach().clone(), "actions": actions.clone(),
                        "values": values.detach().clone(), "returns": returns.clone()})  # fmt: skip
        return loss(log_probs, actions, values, returns, ent_coef, vf_coef, value_loss_form)

    loss = module.a3c_loss
    monkeypatch.setattr(module, "a3c_loss", recorded_loss)
    args = tiny_args(module, envs_per_worker=env.num_envs, learning_rate=0.0, precision="fp32",
                     **flags)  # fmt: skip
    torch.manual_seed(0)
    shared = shared_for(module, args)
    module.worker(0, shared, args)
    return shared.model, updates


@pytest.mark.parametrize("name", ["a3c_ff", "a3c_glpq"])  # the two workers of V(s) networks
def test_the_workers_returns_are_the_n_step_returns_of_its_rollouts(name, monkeypatch, one_thread):
    """Two envs, t_max 4: env 0's episodes end in a terminal state every 3 steps, env 1's in a
    time limit every 5 (both at step 15: a rollout of 3 steps). Each update's states, actions and
    returns, against what the env recorded and returns computed here from theta's values:
    G_t = r_t + gamma G_{t+1} from V(s_n), with G = r_t after a terminal state and
    r_t + gamma V(s_last) after a time limit."""
    module = load_script(name)
    env = ScriptedVectorEnv(lengths=[3, 5], truncates=[False, True])
    gamma = 0.5
    model, updates = scripted_run(
        module, monkeypatch, env, gamma=gamma, t_max=4, total_timesteps=40
    )
    lengths = [len(update["values"]) // env.num_envs for update in updates]
    assert lengths == [4, 4, 4, 3, 4, 4] and len(env.steps) == sum(lengths)

    def value(frames: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return model(torch.from_numpy(np.ascontiguousarray(frames)))[1].numpy()

    start = 0
    for update, n in zip(updates, lengths, strict=True):
        steps = env.steps[start : start + n]
        states = np.concatenate(env.frames[start : start + n])
        scale = float(np.abs(value(states)).max())
        # theta' is theta: the learning pass's values are the shared network's
        np.testing.assert_allclose(update["values"], value(states), rtol=1e-4, atol=1e-5 * scale)
        actions = np.stack([step["actions"] for step in steps])
        np.testing.assert_array_equal(update["actions"].numpy(), actions.ravel())
        g = value(env.frames[start + n])  # V(s_n)
        expected = np.zeros((n, env.num_envs))
        for t in reversed(range(n)):
            step = steps[t]
            end_values = np.zeros(env.num_envs)
            for i in np.flatnonzero(step["truncated"]):
                end_values[i] = value(step["final_obs"][i][None])[0]
            ended = step["terminated"] | step["truncated"]
            g = step["rewards"] + gamma * np.where(ended, end_values, g)
            expected[t] = g
        np.testing.assert_allclose(
            update["returns"].numpy(), expected.ravel(), rtol=1e-4, atol=1e-5 * scale
        )
        start += n


def test_the_worker_samples_its_actions_from_pi(monkeypatch, one_thread):
    """With a uniform policy (zero policy head, learning rate 0) the worker's 2 x 90 actions on
    Catch are each about a third: it samples pi, neither its mode nor a fixed draw."""
    module = load_script("a3c_ff")
    args = tiny_args(module, total_timesteps=180, envs_per_worker=2, learning_rate=0.0)
    shared = shared_for(module, args)
    with torch.no_grad():
        shared.model.policy.weight.zero_()
        shared.model.policy.bias.zero_()
    actions = []
    original = module.a3c_loss

    def recorded_loss(log_probs, actions_taken, *rest):
        actions.append(actions_taken.clone())
        return original(log_probs, actions_taken, *rest)

    monkeypatch.setattr(module, "a3c_loss", recorded_loss)
    module.worker(0, shared, args)
    counts = np.bincount(torch.cat(actions).numpy(), minlength=3)
    assert counts.sum() == 180 and (counts > 40).all(), counts


def test_the_worker_steps_with_the_annealed_rate_and_clipped_gradients(one_thread):
    """Each update's learning rate is eta (1 - T / T_max) at the global step T of its rollout,
    and the gradients the optimizer gets are the clipped ones (per tensor norm <= 1 here, far
    below Catch's unclipped gradients)."""
    module = load_script("a3c_ff")
    args = tiny_args(module, total_timesteps=100, t_max=5, grad_clip=1.0, learning_rate=1e-3)
    shared = shared_for(module, args)
    steps = []
    optimizer_step = shared.optimizer.step

    def recorded_step(grads, lr):
        norms = [float(g.norm()) for g in grads]
        steps.append((shared.global_step(), lr, norms))
        optimizer_step(grads, lr)

    shared.optimizer.step = recorded_step
    module.worker(0, shared, args)
    assert len(steps) == 20
    for global_step, lr, norms in steps:
        assert lr == pytest.approx(1e-3 * (1 - global_step / 100))
        assert max(norms) <= 1.0 + 1e-5
    unclipped = float(shared.stats[0, shared.STATS.index("grad_norm")])
    assert unclipped > 20 * 2.0, "Catch's gradients should need the clipping"


@pytest.mark.parametrize("truncates", [False, True], ids=["terminal", "time-limit"])
def test_the_lstm_worker_learns_from_the_states_it_acted_in(monkeypatch, one_thread, truncates):
    """The LSTM's learning pass replays each rollout from its start state, restarting an env's
    state where its next episode starts: its policy at every step is the one the worker acted
    with. Two envs whose episodes end at different steps (every 3 and 5 steps, t_max 4), so
    that episodes start mid-rollout and at a rollout's start; env 1's end in a terminal state,
    or in a time limit (truncated), after which acting too starts the next from the zero state."""
    module = load_script("a3c_lstm")
    env = ScriptedVectorEnv(lengths=[3, 5], truncates=[False, truncates])
    acting, learning = [], []
    forward = module.ActorCritic.forward

    def recorded_forward(self, obs, state, episode_starts=None):
        out = forward(self, obs, state, episode_starts)
        if obs.shape[1] != env.num_envs:  # V(s_last) of a truncated episode
            pass
        elif episode_starts is None:
            acting.append(out[0].detach().clone())
        else:
            learning.append((len(acting), out[0].detach().clone()))
        return out

    monkeypatch.setattr(module.ActorCritic, "forward", recorded_forward)
    # no activation replay: it would hand the learning pass acting's outputs of the policy and
    # value layers, whatever LSTM state the replay computed their inputs from
    monkeypatch.setattr(module, "replay_activations", lambda model, frames, args: None)
    # frames / 255: on unscaled frames the LSTM's gates saturate and its state hardly matters
    scripted_run(module, monkeypatch, env, t_max=4, total_timesteps=40, scale_obs=True)
    assert len(learning) == 6 and len(acting) == 23  # rollouts of 4, 4, 4, 3, 4 and 4 steps
    start = 0
    for end, log_probs in learning:
        acted = torch.cat(acting[start:end])  # (n, K, A)
        torch.testing.assert_close(log_probs[: end - start], acted, rtol=1e-4, atol=1e-5)
        start = end


def worker_run(module, worker_id: int, steps_before: dict[int, int], **flags) -> list[dict]:
    """Worker `worker_id` of a 2-worker run on Catch, the other workers having taken
    steps_before[w] steps so far; returns each of its updates' global step (of its rollout),
    learning rate and actions."""
    args = runtime.resolve_defaults(module.Args(num_workers=2, **flags))
    torch.manual_seed(0)
    shared = shared_for(module, args)
    for other, steps in steps_before.items():
        shared.steps[other] = steps
    updates = []
    optimizer_step, loss = shared.optimizer.step, module.a3c_loss

    def recorded_loss(log_probs, actions, *rest):
        updates.append({"global_step": shared.global_step(), "actions": actions.clone()})
        return loss(log_probs, actions, *rest)

    def recorded_step(grads, lr):
        updates[-1]["lr"] = lr
        optimizer_step(grads, lr)

    shared.optimizer.step = recorded_step
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(module, "a3c_loss", recorded_loss)
        module.worker(worker_id, shared, args)
    return updates


@pytest.mark.parametrize("name", ["a3c_ff", "a3c_lstm", "a3c_glpq"])  # the workers of their own
def test_the_workers_of_a_run_draw_their_own_random_streams(name, one_thread):
    """Workers 0 and 1 of one run (the same --seed, network and flags, learning rate 0) play
    other games and sample other actions: each seeds its envs and generator by its index."""
    module = load_script(name)
    flags = {"total_timesteps": 60, "t_max": 5, "learning_rate": 0.0, "seed": 3}
    first, second = (worker_run(module, w, {}, **flags) for w in (0, 1))
    assert len(first) == len(second) == 12
    assert not torch.equal(torch.cat([u["actions"] for u in first]),
                           torch.cat([u["actions"] for u in second]))  # fmt: skip
    seeds = {runtime.process_seed(3, index) for index in range(3)}  # 2 workers, the evaluator
    assert len(seeds) == 3


@pytest.mark.parametrize("name", ["a3c_ff", "a3c_lstm", "a3c_glpq"])
def test_the_learning_rate_anneals_with_the_global_step_of_all_workers(name, one_thread):
    """With two workers the rate of worker 1's update is eta (1 - T / T_max) at the run's global
    step T (worker 0's 50 steps included), not at its own count of steps."""
    module = load_script(name)
    updates = worker_run(module, 1, {0: 50}, total_timesteps=100, t_max=5, learning_rate=1e-3)
    assert [u["global_step"] for u in updates] == list(range(50, 100, 5))
    for update in updates:
        assert update["lr"] == pytest.approx(1e-3 * (1 - update["global_step"] / 100))


def test_the_glpq_worker_follows_the_tau_schedule_and_divides_by_tau(monkeypatch, one_thread):
    """Resumed at 90% of T_max, the GLPQ worker's updates scale the policy loss by 1/tau with
    tau = 0.5 ln(p (n - 1) / (1 - p)) at p = p0 + (pN - p0) T / T_max, T the global step of the
    rollout (hot: n = k |A| = 48 on Catch), not the schedule's start."""
    module = load_script("a3c_glpq")
    args = tiny_args(module, total_timesteps=1000, t_max=20)
    shared = shared_for(module, args)
    shared.base_step[0] = 900
    scales = []
    corrected = module.tau_corrected_loss

    def recorded(loss, policy_loss, entropy, scale, args):
        scales.append((shared.global_step(), scale))
        return corrected(loss, policy_loss, entropy, scale, args)

    monkeypatch.setattr(module, "tau_corrected_loss", recorded)
    module.worker(0, shared, args)
    assert len(scales) >= 6
    for global_step, scale in scales:
        p = 0.9 + (0.99 - 0.9) * global_step / 1000
        assert scale == pytest.approx(1 / (0.5 * math.log(p * 47 / (1 - p))), rel=1e-6)
