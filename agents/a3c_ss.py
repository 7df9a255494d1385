# A3C SS: A3C FF whose second convolution feeds a spatial softmax (expected x, y per map).
# Thesis "Deep Reinforcement Learning of Video Games", section 6.2 (eqs. 6.3, 6.4); the rest is
# a copy of a3c_ff.py: `diff agents/a3c_ff.py agents/a3c_ss.py` shows the network and its flags.
# Default: the text's reading (A3C FF's convolutions); --conv-layout final gives the thesis
# code's final 5x5/3, 3x3/2 network.
#
# This file is the algorithm: its flags, the env, the network, the loss and the actor-learner
# loop. The run machinery every script shares is the a3c_runtime package (agents/a3c_runtime/):
# A3C's structure (shared network and optimizer, N actor-learners, an evaluator) is its
# a3c.train; processes and signals, evaluation, checkpoints and logging each have a module.
import math
import os
from dataclasses import dataclass
from typing import Annotated, Literal

import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
from a3c_runtime import (
    Agent,
    Shared,
    UsageError,
    annealed_lr,
    autocast_contexts,
    clip_gradients,
    default_num_workers,
    default_text,
    process_seed,
    replay_activations,
    run,
    sample_actions,
    seed_everything,
)


@dataclass
class Args:
    exp_name: str = os.path.basename(__file__)[: -len(".py")]
    """the name of this experiment (part of the run name)"""
    seed: int = 1
    """seed of the experiment: of the initial network and, with its index, of each process"""
    env: str = "Catch-v0"
    """the Gymnasium id: Catch-v0 or an ALE id such as BreakoutNoFrameskip-v4"""
    total_timesteps: Annotated[int | None, default_text("1e6 for Catch, 1e8 for ALE ids")] = None
    """total global env steps T_max"""
    num_workers: Annotated[int, default_text("the number of CPU cores")] = default_num_workers()
    """the number of actor-learner processes"""
    envs_per_worker: int = 1
    """K, the envs each worker steps together: it acts on all K with one batched forward and
    learns from the K x t_max rollout in one update (batched actors inside each Hogwild worker,
    as in PAAC, Clemente et al. 2017); 1 is the thesis's algorithm"""
    time_limit: float | None = None
    """stop training after this many seconds; the evaluations due and the final one run after it"""

    # Algorithm (thesis Table 5.1)
    learning_rate: float = 7e-4
    """the learning rate eta"""
    anneal_lr: bool = True
    """anneal the learning rate linearly to 0 at T_max (by the shared global step)"""
    t_max: int = 20
    """the rollout length: steps per update, fewer when the episode ends"""
    gamma: float = 0.99
    """the discount factor gamma"""
    ent_coef: float = 0.01
    """the entropy factor beta"""
    vf_coef: float = 0.5
    """the value loss factor lambda_V (thesis 6.4.1): the factor of --value-loss-form's loss"""
    value_loss_form: Literal["code", "text"] = "code"
    """the value loss: code, vf_coef * 0.5 * (G - V)^2, as the thesis's code computed it
    (TensorFlow's l2_loss) in every thesis run; text, vf_coef * (G - V)^2, as Algorithm 1 writes
    it (twice code's value gradient at the same vf_coef)"""
    precision: Literal["auto", "fp32", "bf16", "bf16-learn", "tf32"] = "auto"
    """the workers' network passes: fp32; bf16: acting and learning under bfloat16 CPU autocast;
    bf16-learn: acting in fp32, the learning pass (its forward computed again, and its
    gradients) in bf16. Weights, optimizer statistics, returns and the loss stay float32; the
    evaluator and --evaluate play in fp32. auto: fp32 with K = 1 (the thesis's algorithm and
    precision) on every CPU; with K > 1 envs per worker, bf16 on a CPU with native bf16, fp32
    elsewhere (results/throughput_batched). bf16-learn, faster at K = 1 where bf16 is native
    (results/precision_catch), is another computation: one flag away. tf32: fp32 with a GPU's
    TF32 matrix multiplies and convolutions, for the sweep's batched backend on --device cuda
    only (the workers compute on the CPU)"""

    # Optimizer (thesis 2.2.3, 5.2.2, A.1.2)
    optimizer: Literal["rmsprop", "adam"] = "rmsprop"
    """the shared optimizer; its statistics live in shared memory and are updated without locks"""
    rms_decay: float = 0.99
    """RMSprop decay rho of the mean square"""
    adam_beta1: float = 0.9
    """Adam's first-moment decay beta1"""
    adam_beta2: float = 0.99
    """Adam's second-moment decay beta2 (thesis A.1.2 says 0.99; the thesis's runs used 0.999)"""
    adam_epsilon_form: Literal["text", "code"] = "text"
    """Adam's epsilon: text, m_hat / sqrt(v_hat + eps) (eq. A.5); code, as the thesis's runs
    computed it (the bias correction folded into the learning rate), eps / (1 - beta2^t) in place
    of eps: 1000 eps at the first update with beta2 0.999, near eps after some 5,000"""
    optim_eps: float = 0.1
    """the optimizer epsilon, inside the square root: g / sqrt(ms + eps)"""
    rms_init: float = 0.0
    """RMSprop's initial mean square ms: 0 as in the thesis's code; 1 as TensorFlow's
    RMSPropOptimizer (OpenAI baselines' A2C, whose --optim-eps 1e-5 assumes it): from 0 with a
    small eps the first updates are about 10 lr per weight, from 1 they start small"""
    grad_clip_mode: Literal["norm", "value", "global-norm", "none"] = "norm"
    """gradient clipping: norm, each tensor by its norm, as the thesis's code
    (tf.clip_by_norm); value, each element, as section 6.3.1 writes it; global-norm (6.3.1's
    c_g); or none"""
    grad_clip: Annotated[float | None, default_text("40; c_g = 25 for global-norm")] = None
    """the clipping bound"""

    # Network (thesis 5.2.1 and chapter 6)
    activation: Literal["relu", "elu"] = "relu"
    """the hidden-layer activation (thesis 6.3.2)"""
    weight_init: Literal["torch", "he", "variance-scaling", "uniform-sqrt3"] = "torch"
    """weights: torch U(+-1/sqrt(fan_in)); he: truncated normal std sqrt(2/fan_in) (6.3.3);
    variance-scaling: TensorFlow's variance_scaling_initializer, the thesis runs' He init, std
    sqrt(2.6/fan_in) before its 2-std truncation; uniform-sqrt3: U(+-sqrt(3)/sqrt(fan_in))"""
    bias_init: Annotated[float | None, default_text("torch init's, else 0")] = None
    """a constant for every bias (thesis A.1.3 uses 0.01); by default U(+-1/sqrt(fan_in)) with
    torch init, 0 with the other weight inits"""
    scale_obs: Annotated[bool | None, default_text("True for ALE, False for Catch")] = None
    """divide frames by 255 (the thesis fed Catch 0..255)"""
    terminal_on_life_loss: bool = False
    """ALE ids: a lost life ends the learner's episode but not the game, as in DeepMind's Atari
    setup (catch_env.wrappers.EpisodicLifeEnv); evaluations play whole games. Off, an episode
    ends at game over, as in the thesis's runs"""

    # Spatial softmax (thesis 6.2)
    conv_layout: Literal["ff", "final"] = "ff"
    """the convolutions: ff = A3C FF's conv 32 8x8/4, conv 64 4x4/2 (84 -> 20 -> 9; the thesis
    text, 6.2.1, and most likely the Figure 6.5 runs); final = the thesis code's final conv 32
    5x5/3, conv 64 3x3/2 (84 -> 27 -> 13)"""
    ss_temperature: Literal["per-map", "global"] = "per-map"
    """the softmax temperature: one tau_k per map (the text's A3C SS TT) or one global tau (the
    text's A3C SS GT TT). Figure 6.5 as run (the thesis code inverted a flag): "SS" = global,
    "SS TT" = global with --no-ss-trainable-temperature, "SS GT TT" = per-map"""
    ss_trainable_temperature: bool = True
    """train the temperature by gradient descent; else it stays at its initial value"""
    ss_initial_temperature: float = 0.6
    """the temperature's initial value"""

    # Evaluation, logging, checkpoints
    eval_interval: Annotated[int | None, default_text("50,000 for Catch, 1,000,000 for ALE")] = None
    """global steps between evaluations"""
    eval_episodes: Annotated[int | None, default_text("50; --evaluate: the run's")] = None
    """episodes per evaluation, sampling actions from pi"""
    eval_greedy: bool = False
    """evaluations (and --evaluate) play argmax pi instead of sampling from pi (the thesis
    samples; greedy play tells how much of a score the policy's randomness costs)"""
    checkpoint_interval: Annotated[int | None, default_text("the evaluation interval")] = None
    """global steps between checkpoints; also at the end"""
    log_interval: float = 5.0
    """seconds between console progress lines and TensorBoard scalars"""
    track: bool = False
    """log the run to Weights & Biases (the `wandb` extra): the TensorBoard scalars synced, the
    flags as its config"""
    wandb_project_name: str = "deep-rl-video-games"
    """the W&B project of --track"""
    wandb_entity: str | None = None
    """the W&B entity (team or user) of --track; by default yours"""
    runs_root: str = "runs"
    """the folder that gets a new run folder runs_root/<run_name>"""
    run_dir: str | None = None
    """the run folder, instead of runs_root/<run_name> (with --resume: the checkpoint's)"""
    resume: str | None = None
    """a checkpoint.pt to continue training from (network, optimizer statistics, global step)"""
    capture_video: bool = False
    """record evaluation episodes (one per evaluation) to <run_dir>/videos"""
    evaluate: str | None = None
    """play the run's evaluation at this checkpoint's step (its episodes and action samples;
    --seed, --eval-episodes, --eval-greedy replace the run's), print the scores, exit
    (--capture-video records them to videos-evaluate next to it)"""
    render: Literal["none", "human"] = "none"
    """with --evaluate: 'human' shows the episodes in a window"""


def make_env(env_id: str, render_mode: str | None = None) -> gym.Env:
    """The thesis preprocessing from catch_env.wrappers: 4 stacked 84x84 uint8 frames, Atari
    action repeat 4 and reward clipping; info["episode"]["r"] is the raw game score."""
    from catch_env.wrappers import make_env as make_wrapped_env

    return make_wrapped_env(env_id, render_mode=render_mode)


def make_vector_env(
    env_id: str, num_envs: int, terminal_on_life_loss: bool = False
) -> gym.vector.VectorEnv:
    """make_env's preprocessing for num_envs envs stepped together (Catch: its NumPy vector
    env; ALE: ale-py's C++ vector env, one emulator thread); an ended episode's env is reset in
    the same step (catch_env.wrappers.make_vector_env). With terminal_on_life_loss (ALE ids
    only), a lost life ends the episode but not the game."""
    from catch_env.wrappers import make_vector_env as make_wrapped_vector_env

    life_loss = {"terminal_on_life_loss": True} if terminal_on_life_loss else {}
    return make_wrapped_vector_env(env_id, num_envs, **life_loss)


# ----------------------------------------------------------------------------------------------
# The network. Variants (LWS, SS, WW, LSTM, LPQ, GLPQ) replace this class and NETWORK_ARGS.
# Contract: forward(obs uint8 (B, 4, 84, 84)) -> (log-probabilities (B, A), values (B,)).
# ----------------------------------------------------------------------------------------------
# args a checkpoint's network depends on; the initial temperature too, since a fixed one is a
# buffer that every process builds from it
NETWORK_ARGS = ("env", "activation", "scale_obs", "conv_layout", "ss_temperature",
                "ss_trainable_temperature", "ss_initial_temperature")  # fmt: skip


class SpatialSoftmax(nn.Module):
    """Spatial softmax (thesis 6.2, eqs. 6.3 and 6.4; Levine et al. 2016). Per map k a softmax
    over positions, psi(F_k)_ij = exp(F_kij / tau_k) / sum_uv exp(F_kuv / tau_k), and its
    expected coordinates Y_2k = sum_ij psi_ij x_j, Y_2k+1 = sum_ij psi_ij y_i, with x_j (column)
    and y_i (row, downwards) evenly spaced in [-0.5, 0.5]. (B, K, H, W) -> (B, 2K)."""

    def __init__(self, maps: int, size: int, args: Args):
        super().__init__()
        if not (args.ss_initial_temperature > 0 and math.isfinite(args.ss_initial_temperature)):
            raise UsageError(
                f"--ss-initial-temperature must be > 0 (got {args.ss_initial_temperature})"
            )
        axis = torch.linspace(-0.5, 0.5, size)
        x, y = torch.meshgrid(axis, axis, indexing="xy")  # x[i, j] = axis[j], y[i, j] = axis[i]
        self.register_buffer("coordinates", torch.stack([x, y], -1).view(-1, 2), persistent=False)
        shape = (maps, 1) if args.ss_temperature == "per-map" else (1, 1)
        temperature = torch.full(shape, args.ss_initial_temperature)
        if args.ss_trainable_temperature:
            self.temperature = nn.Parameter(temperature)
        else:
            self.register_buffer("temperature", temperature)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        softmax = torch.softmax(features.flatten(2) / self.temperature, dim=-1)  # (B, K, H*W)
        return (softmax @ self.coordinates).flatten(1)  # (B, K, 2) -> x_1, y_1, x_2, y_2, ...


class ActorCritic(nn.Module):
    """A3C SS (thesis 6.2.1: "the second convolutional layer is replaced by a spatial softmax
    layer. The remainder of the architecture is identical to that of A3C FF"): conv 32 ReLU,
    conv 64 (linear), spatial softmax over its 64 maps -> 128 coordinates, FC 256, softmax
    policy, linear value. The convolutions (--conv-layout): ff (default, the text's reading and
    most likely the Figure 6.5 runs', see thesis-notes.md "As run") 8x8/4 and 4x4/2, 9x9 maps;
    final (the thesis code's final network) 5x5/3 and 3x3/2, 13x13 maps."""

    def __init__(self, num_actions: int, args: Args):
        super().__init__()
        activation = {"relu": nn.ReLU, "elu": nn.ELU}[args.activation]
        # (kernel, stride) of each convolution: 84 -> 20 -> 9 (ff) or 84 -> 27 -> 13 (final)
        (k1, s1), (k2, s2) = {"ff": ((8, 4), (4, 2)), "final": ((5, 3), (3, 2))}[args.conv_layout]
        size = ((84 - k1) // s1 + 1 - k2) // s2 + 1  # the second convolution's output size
        self.torso = nn.Sequential(  # in-place activations: fewer allocations, same gradients
            nn.Conv2d(4, 32, k1, stride=s1),
            activation(inplace=True),
            nn.Conv2d(32, 64, k2, stride=s2),  # no activation: the softmax follows
            SpatialSoftmax(64, size, args),
            nn.Linear(2 * 64, 256),
            activation(inplace=True),
        )
        self.policy = nn.Linear(256, num_actions)
        self.value = nn.Linear(256, 1)
        self.obs_scale = 1.0 / 255.0 if args.scale_obs else 1.0
        init_parameters(self, args.weight_init, args.bias_init)

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # channels_last makes oneDNN's convolution backward about 2x faster on CPU
        x = obs.to(dtype=torch.float32, memory_format=torch.channels_last)
        if self.obs_scale != 1.0:
            x = x * self.obs_scale
        hidden = self.torso(x)
        return F.log_softmax(self.policy(hidden), dim=-1), self.value(hidden).squeeze(-1)


# ----------------------------------------------------------------------------------------------


def init_parameters(model: nn.Module, weight_init: str, bias_init: float | None) -> None:
    """Initialise every Conv2d/Linear layer with the thesis 6.3.3 scheme; biases per A.1.3."""
    for layer in model.modules():
        if not isinstance(layer, (nn.Conv2d, nn.Linear)):
            continue
        fan_in = layer.weight[0].numel()
        if weight_init in ("he", "variance-scaling"):
            # TensorFlow's scales by 1.3 so that, truncated at 2 std, the variance is 2 / fan_in
            std = math.sqrt((2.6 if weight_init == "variance-scaling" else 2.0) / fan_in)
            nn.init.trunc_normal_(layer.weight, std=std, a=-2 * std, b=2 * std)
        elif weight_init == "uniform-sqrt3":
            bound = math.sqrt(3.0 / fan_in)
            nn.init.uniform_(layer.weight, -bound, bound)
        # "torch": keep PyTorch's default, which is Torch7's U(-1/sqrt(fan_in), 1/sqrt(fan_in))
        if bias_init is not None:
            nn.init.constant_(layer.bias, bias_init)
        elif weight_init != "torch":
            nn.init.zeros_(layer.bias)


def n_step_returns(
    rewards: np.ndarray,
    dones: np.ndarray,
    done_values: np.ndarray,
    bootstrap_values: np.ndarray,
    gamma: float,
) -> np.ndarray:
    """The n-step returns of a rollout of K envs, all (T, K) but bootstrap_values (K,):
    G_t = r_t + gamma * G_{t+1} from G_T = V(s_T), the last state's value, except where an
    episode ended at step t (dones): there G_t = r_t + gamma * done_values_t, which is 0 after a
    terminal state and V(last state) after a truncation. NumPy arrays, or tensors (the batched
    backend's, on its device): the choice by the dones is a sum of products, exact for finite
    values (x * 1 + y * 0 is x), so both give np.where's values."""
    returns = rewards * 0
    g = bootstrap_values
    for t in range(len(rewards) - 1, -1, -1):
        g = rewards[t] + gamma * (dones[t] * done_values[t] + ~dones[t] * g)
        returns[t] = g
    return returns


def a3c_loss(
    log_probs: torch.Tensor,
    actions: torch.Tensor,
    values: torch.Tensor,
    returns: torch.Tensor,
    ent_coef: float,
    vf_coef: float,
    value_loss_form: str = "code",
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]:
    """The A3C loss summed over the rollout (Algorithm 1): policy gradient with the advantage
    not back-propagated, minus beta * entropy, plus lambda_V times the value loss: 0.5 * (G - V)^2
    with value_loss_form "code" (TensorFlow's l2_loss, as the thesis's code), (G - V)^2 with
    "text" (Algorithm 1, line 16).
    Returns (loss, policy_loss, value_loss, entropy), the last three before their factors."""
    advantages = returns - values
    policy_loss = -(log_probs.gather(1, actions[:, None]).squeeze(1) * advantages.detach()).sum()
    entropy = -(log_probs.exp() * log_probs).sum()
    value_loss = advantages.pow(2).sum()
    if value_loss_form == "code":
        value_loss = 0.5 * value_loss
    return policy_loss - ent_coef * entropy + vf_coef * value_loss, policy_loss, value_loss, entropy


def worker(worker_id: int, shared: Shared, args: Args) -> None:
    """One actor-learner (Algorithm 1): sync, act t_max steps, one batched update, repeat.
    With --envs-per-worker K it steps K envs, acting on all K with one batched forward, and
    learns from the K x t_max rollout in one update. The rollout ends early only when every
    env's episode ends at the same step: with K = 1, at the end of the episode, as in the thesis."""
    seed = process_seed(args.seed, worker_id)
    seed_everything(seed)
    rng = np.random.default_rng(seed)
    envs = make_vector_env(args.env, args.envs_per_worker, args.terminal_on_life_loss)
    num_envs = envs.num_envs
    model = ActorCritic(envs.single_action_space.n, args).to(memory_format=torch.channels_last)
    params = list(model.parameters())
    # the frames of the rollout (t_max + 1, K, 4, 84, 84), each step's K frames channels-last
    # like the network's input (see ActorCritic), and any steps' rows a view of one batch
    channels, height, width = envs.single_observation_space.shape
    obs_buf = torch.zeros((args.t_max + 1, num_envs, height, width, channels), dtype=torch.uint8)
    obs_buf = obs_buf.permute(0, 1, 4, 2, 3)
    actions = np.zeros((args.t_max, num_envs), dtype=np.int64)
    rewards = np.zeros((args.t_max, num_envs), dtype=np.float32)
    dones = np.zeros((args.t_max, num_envs), dtype=bool)  # an episode ended at this step
    done_values = np.zeros((args.t_max, num_envs), dtype=np.float32)  # V(s_last) if truncated
    stats = shared.worker_stats(worker_id)  # Shared.STATS, added to by name
    obs, _ = envs.reset(seed=seed)

    def worker_state() -> tuple:  # what a checkpoint keeps of this worker, for an exact resume
        return rng, envs, obs_buf[0].numpy()

    # a resumed run goes on where its checkpoint left this worker (a3c_runtime.snapshots)
    rng, envs, obs = shared.resumed(worker_id, rng, envs, obs)
    obs_buf[0].copy_(torch.from_numpy(obs))
    # --precision: the acting and the learning forward passes under bf16 autocast or not, their
    # outputs cast to float32 for the sampling and the loss; backward and optimizer outside it
    act_precision, learn_precision = autocast_contexts(args.precision)
    # where it pays, the learning forward over obs_buf takes back the conv and linear outputs
    # that acting computed (same theta', same states) instead of computing them again
    replay_activations(model, obs_buf, args)

    while shared.keep_running():
        global_step = shared.global_step()
        if global_step >= args.total_timesteps:
            break
        with torch.no_grad():
            torch._foreach_copy_(params, shared.params)  # theta' <- theta
        # act with the synced local network for t_max steps (or until every episode ends)
        dones[:] = False
        with torch.inference_mode(), act_precision:
            for t in range(args.t_max):
                log_probs, _ = model(obs_buf[t])
                action = sample_actions(log_probs.float().exp().numpy(), rng.random(num_envs))
                # an ended episode's env returns its next episode's first frame (autoreset)
                obs, reward, terminated, truncated, info = envs.step(action)
                actions[t], rewards[t] = action, reward
                obs_buf[t + 1].copy_(torch.from_numpy(obs))
                ended = terminated | truncated
                if ended.any():
                    dones[t] = ended
                    episodes = info["final_info"]["_episode"]
                    stats.add(
                        episodes=int(episodes.sum()),
                        return_sum=float(info["final_info"]["episode"]["r"][episodes].sum()),
                        length_sum=int(info["final_info"]["episode"]["l"][episodes].sum()),
                    )
                    done_values[t] = 0.0
                    cut = truncated & ~terminated  # a time limit: bootstrap from V(s_last)
                    if cut.any():
                        last_obs = torch.from_numpy(np.stack(info["final_obs"][cut]))
                        done_values[t, cut] = model(last_obs)[1].float().numpy()
                    if ended.all():
                        break
        n = t + 1
        # one batched forward/backward over the n x K states; row n gives V(s_n) to bootstrap
        # from, unless every episode has ended there
        bootstrap = not dones[n - 1].all()
        with learn_precision:
            log_probs, values = model(obs_buf[: n + 1 if bootstrap else n].flatten(0, 1))
        log_probs, values = log_probs.float(), values.float()  # the loss in float32
        bootstrap_values = values[n * num_envs :].detach().numpy() if bootstrap else 0.0
        returns = n_step_returns(
            rewards[:n], dones[:n], done_values[:n], bootstrap_values, args.gamma
        )
        loss, policy_loss, value_loss, entropy = a3c_loss(
            log_probs[: n * num_envs],
            torch.from_numpy(actions[:n].ravel()),
            values[: n * num_envs],
            torch.from_numpy(returns.ravel()),
            args.ent_coef,
            args.vf_coef,
            args.value_loss_form,
        )
        grads = torch.autograd.grad(loss, params)
        grad_norm = clip_gradients(grads, args.grad_clip_mode, args.grad_clip)
        shared.optimizer.step(grads, annealed_lr(args, global_step))

        obs_buf[0].copy_(obs_buf[n])  # the next rollout starts where this one stopped
        # the steps taken; at an evaluation or checkpoint mark theta is copied there
        shared.count_steps(worker_id, n * num_envs, worker_state)
        stats.add(
            updates=1,
            policy_loss=policy_loss.item(),
            value_loss=value_loss.item(),
            entropy=entropy.item(),
            grad_norm=grad_norm,
        )
    shared.finish_worker(worker_id, worker_state)  # for the run's last checkpoint
    envs.close()


AGENT = Agent(
    script=os.path.basename(__file__),
    Args=Args,
    make_env=make_env,
    network=ActorCritic,
    network_args=NETWORK_ARGS,
    worker=worker,
    # checkpoints from before --conv-layout existed hold the final code's network
    checkpoint_defaults={"conv_layout": "final"},
)


def main() -> int:
    """Train (a3c_runtime.a3c.train), or play a checkpoint's episodes with --evaluate; see
    --help for every flag."""
    return run(AGENT)


if __name__ == "__main__":
    raise SystemExit(main())
