# A3C LPQ with dynamic prototypes: chapter 8's "dynamically adding or removing prototypes".
# Each action has --max-prototypes-per-action slots, --prototypes-per-action of them active at the
# start; every --growth-interval global steps worker 0 grows a prototype on a far state and prunes
# an idle one (grow_and_prune). A copy of a3c_lpq.py: only the flags, the network (its slots and
# their mask) and worker 0's growth step differ.
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

    # Prototype policy (thesis chapter 7: LPQ, eqs. 7.5, 7.9, 7.11)
    prototypes_per_action: int = 16
    """prototypes per action in the 256-d feature space"""
    distance: Literal["squared-euclidean", "euclidean", "manhattan", "cosine", "pearson",
                      "inverse-squared-euclidean"] = "squared-euclidean"  # fmt: skip
    """the distance d(h, w) (thesis 7.2.1)"""
    competition_size: Annotated[int | None, default_text("all")] = None
    """k: only the k nearest prototypes of each action compete (eq. 7.11)"""
    prototype_init: Literal["uniform", "uniform-positive", "uniform-clipped"] = "uniform"
    """prototypes U(-b, b); uniform-positive: U(0, b), the thesis code's option (zpi);
    uniform-clipped: U(-b, b) with negatives set to 0, as the ReLU features are (our reading of
    the thesis's unexplained 'zero clipping', figure C.1)"""
    prototype_init_bound: float = 1 / 16
    """the bound b of the prototype initialisation"""
    max_prototypes_per_action: Annotated[
        int | None, default_text("2 x --prototypes-per-action")
    ] = None
    """the slots per action; --prototypes-per-action of them start active"""
    growth_interval: int = 50_000
    """global steps between growth steps: every --growth-interval global steps, on the states of a
    short rollout of the current policy, each action may gain a prototype on its farthest state
    (when that is --growth-ratio times the mean distance away) and lose one that is no state's
    nearest (grow_and_prune)"""
    growth_ratio: float = 2.0
    """a prototype is added for action a when a state that chose a is this many times the mean
    distance (over all states, to their action's nearest prototype) away from a's nearest
    prototype"""

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
# args a checkpoint's network depends on
NETWORK_ARGS = ("env", "activation", "scale_obs", "prototypes_per_action", "distance",
                "competition_size", "max_prototypes_per_action")  # fmt: skip
NORM_EPS = 1e-8  # below this norm a vector counts as zero (cosine and Pearson distances)
SQRT_EPS = 1e-12  # the Euclidean distance is sqrt(max(squared, SQRT_EPS)): no infinite gradient


def unit_vectors(x: torch.Tensor) -> torch.Tensor:
    """x / |x| along the last axis; a zero vector has no direction and stays 0, with a zero
    gradient rather than NaN (torch.where on a safe denominator)."""
    norm = torch.linalg.vector_norm(x, dim=-1, keepdim=True)
    nonzero = norm > NORM_EPS
    return torch.where(nonzero, x / torch.where(nonzero, norm, 1.0), 0.0)


# float32 whatever --precision: under bf16 autocast the expansion |h|^2 - 2 h.w + |w|^2 below
# cancels to noise (3 significant digits): a distance of 0.5 came out as 0, errors up to 38
@torch.autocast("cpu", enabled=False)
def prototype_distances(
    features: torch.Tensor, prototypes: torch.Tensor, distance: str
) -> torch.Tensor:
    """d(h, w) of thesis 7.2.1 between each feature row (B, D) and prototype (M, D) -> (B, M),
    in float32. Cosine and Pearson give 1 (orthogonal) where a vector is zero (or constant, for
    Pearson)."""
    features, prototypes = features.float(), prototypes.float()
    if distance in ("cosine", "pearson"):
        if distance == "pearson":  # the cosine distance of the mean-centred vectors
            features = features - features.mean(-1, keepdim=True)
            prototypes = prototypes - prototypes.mean(-1, keepdim=True)
        # clamped: rounding must not make d(h, h) negative (GLPQ's mu would leave [-1, 1])
        return (1.0 - unit_vectors(features) @ unit_vectors(prototypes).T).clamp_min(0.0)
    if distance == "manhattan":
        return torch.cdist(features, prototypes, p=1.0)
    # |h - w|^2 = |h|^2 - 2 h.w + |w|^2: a matrix product, several times faster to train than
    # the (B, M, D) difference; clamped, as rounding can take it slightly below 0
    squared = torch.addmm(prototypes.square().sum(-1), features, prototypes.T, alpha=-2.0)
    squared = (squared + features.square().sum(-1, keepdim=True)).clamp_min(0.0)
    if distance == "squared-euclidean":
        return squared
    if distance == "euclidean":
        return squared.clamp_min(SQRT_EPS).sqrt()
    if distance == "inverse-squared-euclidean":  # a similarity turned into a "distance"
        return -1.0 / (1.0 + squared)
    raise ValueError(f"unknown distance {distance!r}")


def nearest_prototypes(distances: torch.Tensor, k: int) -> torch.Tensor:
    """The competition B of eq. 7.11: the distances (B, A, P) of each action's k nearest
    prototypes -> (B, A, k)."""
    if k == distances.shape[-1]:
        return distances
    return distances.topk(k, dim=-1, largest=False, sorted=False).values


def lpq_log_policy(distances: torch.Tensor, k: int) -> torch.Tensor:
    """log pi(a) of eq. 7.9 from the distances (B, A, P): log sum over a's competing prototypes
    of exp(-d) minus log sum over all competing prototypes."""
    distances = nearest_prototypes(distances, k)
    # log sum_p exp(-d_p) = log sum_p exp(m - d_p) - m with m = min_p d_p: the terms lie in
    # (0, 1] and one is 1, so nothing overflows or sums to 0. The same as logsumexp (m is a
    # constant to the gradient), at a fraction of its generic CPU kernel's cost.
    nearest = distances.detach().amin(dim=-1, keepdim=True)  # (B, A, 1)
    per_action = torch.exp(nearest - distances).sum(-1).log() - nearest.squeeze(-1)  # (B, A)
    return F.log_softmax(per_action, dim=-1)


class ActorCritic(nn.Module):
    """A3C LPQ (thesis 7.1.2, 7.2): the A3C FF torso and value head; the policy is a softmax of
    the negative distances from the 256-d feature h to P prototypes per action, summed per
    action (eq. 7.9), over each action's k nearest prototypes (eq. 7.11)."""

    def __init__(self, num_actions: int, args: Args):
        super().__init__()
        activation = {"relu": nn.ReLU, "elu": nn.ELU}[args.activation]
        self.torso = nn.Sequential(  # in-place activations: fewer allocations, same gradients
            nn.Conv2d(4, 32, 8, stride=4),
            activation(inplace=True),
            nn.Conv2d(32, 64, 4, stride=2),
            activation(inplace=True),
            nn.Flatten(),
            nn.Linear(64 * 9 * 9, 256),
            activation(inplace=True),
        )
        self.value = nn.Linear(256, 1)
        self.obs_scale = 1.0 / 255.0 if args.scale_obs else 1.0
        init_parameters(self, args.weight_init, args.bias_init)
        per_action, k = args.prototypes_per_action, args.competition_size
        slots = args.max_prototypes_per_action or 2 * per_action  # per_action start active
        if not per_action <= slots or args.distance == "inverse-squared-euclidean":
            raise UsageError(
                "growth needs --max-prototypes-per-action >= --prototypes-per-action "
                f"(got {slots} < {per_action}) and a distance >= 0"
            )
        if not (args.growth_interval > 0 and args.growth_ratio > 0):
            raise UsageError("--growth-interval and --growth-ratio must be > 0")
        self.competition_size = slots if k is None else k
        if per_action < 1 or not 1 <= self.competition_size <= slots:
            raise UsageError(
                "--prototypes-per-action must be >= 1 and --competition-size in [1, the "
                f"prototypes per action, {slots}] (got {per_action} and {args.competition_size})"
            )
        if not args.prototype_init_bound > 0:
            raise UsageError(
                f"--prototype-init-bound must be > 0 (got {args.prototype_init_bound})"
            )
        self.num_actions, self.distance = num_actions, args.distance
        # rows a * P ... a * P + P - 1 belong to action a (P: the slots)
        self.prototypes = nn.Parameter(torch.empty(num_actions * slots, 256))
        bound = args.prototype_init_bound
        with torch.no_grad():
            low = 0.0 if args.prototype_init == "uniform-positive" else -bound
            self.prototypes.uniform_(low, bound)
            if args.prototype_init == "uniform-clipped":
                self.prototypes.clamp_(min=0.0)
        # 1 for an active slot, 0 for a free one. A parameter, so that theta's sync brings it to
        # every worker, used detached so that its gradient is 0 and no optimizer moves it: only
        # grow_and_prune writes it
        active = torch.zeros(num_actions, slots)
        active[:, :per_action] = 1.0
        self.prototype_active = nn.Parameter(active.flatten())
        # the last growth step done, in the checkpoint so that a resumed run neither skips nor
        # repeats one
        self.register_buffer("growth_round", torch.zeros((), dtype=torch.long))

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # channels_last makes oneDNN's convolution backward about 2x faster on CPU
        x = obs.to(dtype=torch.float32, memory_format=torch.channels_last)
        if self.obs_scale != 1.0:
            x = x * self.obs_scale
        hidden = self.torso(x)
        return self.log_policy(hidden), self.value(hidden).squeeze(-1)

    def features(self, obs: torch.Tensor) -> torch.Tensor:
        """h (B, 256) of the frames (B, 4, 84, 84), as forward computes it."""
        x = obs.to(dtype=torch.float32, memory_format=torch.channels_last)
        if self.obs_scale != 1.0:
            x = x * self.obs_scale
        return self.torso(x)

    def active_slots(self) -> torch.Tensor:
        """(A, P) bool, True for the active prototypes."""
        return (self.prototype_active.detach() > 0.5).view(self.num_actions, -1)

    def zero_gradient_anchor(self) -> torch.Tensor:
        """0, through the slot mask, so that it is in the graph with a zero gradient (a dense
        one: the gradient of a plain sum would be an expanded tensor, which clipping cannot
        scale in place)."""
        return (0.0 * self.prototype_active).sum()

    def log_policy(self, hidden: torch.Tensor) -> torch.Tensor:
        """log pi (B, A) from the features h (B, 256)."""
        distances = prototype_distances(hidden, self.prototypes, self.distance)
        distances = distances.view(len(hidden), self.num_actions, -1)  # (B, A, P)
        # a free slot is infinitely far: its exp(-d) is 0
        distances = distances.masked_fill(~self.active_slots(), math.inf)
        return lpq_log_policy(distances, self.competition_size) + self.zero_gradient_anchor()


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
        if worker_id == 0:  # growth: between worker 0's updates, once per --growth-interval
            maintain_prototypes(shared, args, shared.global_step())
    shared.finish_worker(worker_id, worker_state)  # for the run's last checkpoint
    envs.close()


GROWTH_ENVS, GROWTH_STEPS = 16, 32  # each growth step: 512 states of the current policy


def grow_and_prune(
    distances: torch.Tensor, actions: torch.Tensor, active: torch.Tensor, ratio: float
) -> tuple[dict[int, int], dict[int, tuple[int, int]]]:
    """The growth rule on N states: distances (N, A, P) from each state's features
    to every slot of every action, actions (N,) the actions the policy took there, active
    (A, P) the slots in use. For each action a that some state took:
    - prune: an active prototype of a that is no state's nearest among a's prototypes (over the
      states that took a), while a keeps another: of those, the farthest on average from them;
    - grow: where the state that took a farthest from a's nearest prototype is more than ratio
      times the mean of that distance (over all N states, each to its action's nearest
      prototype) away, a prototype on that state, in the slot just pruned or a free one.
    Returns ({a: the slot pruned}, {a: (the slot grown, the state's index)})."""
    masked = distances.masked_fill(~active, math.inf)
    own = masked[torch.arange(len(actions)), actions]  # (N, P): to the taken action's slots
    nearest, winner = own.min(-1)
    scale = nearest.mean()  # not the median: with prototypes on states, most distances are 0
    pruned, grown = {}, {}
    for a in actions.unique().tolist():
        rows = torch.where(actions == a)[0]
        wins = torch.bincount(winner[rows], minlength=active.shape[1])
        idle = active[a] & (wins == 0)
        if idle.any() and active[a].sum() > 1:
            mean = own[rows].mean(0)
            pruned[a] = int(torch.where(idle, mean, -math.inf).argmax())
        state = int(rows[nearest[rows].argmax()])
        free = ~active[a]
        if a in pruned:
            free[pruned[a]] = True
        if nearest[state] > ratio * scale > 0 and free.any():
            slot = pruned[a] if a in pruned else int(free.nonzero()[0])
            grown[a] = (slot, state)
    return pruned, grown


def maintain_prototypes(shared: Shared, args: Args, global_step: int) -> None:
    """Worker 0, between its updates: once per --growth-interval global steps, grow_and_prune on
    the states of GROWTH_STEPS steps of GROWTH_ENVS envs under the current global policy (actions
    sampled from pi). A grown prototype sits on its state's features, its optimizer statistics
    restarted; the workers get the new slots with theta."""
    model, due = shared.model, global_step // args.growth_interval
    if due <= int(model.growth_round):
        return
    model.growth_round.fill_(due)
    if hasattr(model, "set_progress"):
        model.set_progress(global_step / args.total_timesteps)
    rng = np.random.default_rng([args.seed, due])
    envs = make_vector_env(args.env, GROWTH_ENVS)
    obs, _ = envs.reset(seed=int(rng.integers(2**31)))
    frames, actions = [], []
    with torch.no_grad():
        for _ in range(GROWTH_STEPS):
            probs = model(torch.from_numpy(obs))[0].float().exp().numpy()
            action = sample_actions(probs, rng.random(len(obs)))
            frames.append(obs.copy())  # the env may reuse its buffer
            actions.append(action)
            obs, *_ = envs.step(action)
        envs.close()
        hidden = model.features(torch.from_numpy(np.concatenate(frames)))
        distances = prototype_distances(hidden, model.prototypes, model.distance)
        active = model.active_slots()
        distances = distances.view(len(hidden), *active.shape)
        taken = torch.from_numpy(np.concatenate(actions))
        pruned, grown = grow_and_prune(distances, taken, active, args.growth_ratio)
        slots, mask = active.shape[1], model.prototype_active
        for a, slot in pruned.items():
            mask[a * slots + slot] = 0.0
        for a, (slot, state) in grown.items():
            model.prototypes[a * slots + slot] = hidden[state]
            mask[a * slots + slot] = 1.0
        index = next(i for i, p in enumerate(shared.params) if p is model.prototypes)
        restart_statistics(shared.optimizer, index, [a * slots + s for a, (s, _) in grown.items()])
    if pruned or grown:
        counts = model.active_slots().sum(1).tolist()
        print(
            f"prototype growth at step {global_step:,}: pruned for actions {sorted(pruned)}, "
            f"grown for {sorted(grown)}; active per action {counts}",
            flush=True,
        )


@torch.no_grad()
def restart_statistics(optimizer: object, index: int, rows: list[int]) -> None:
    """The shared optimizer's statistics of rows of parameter `index` as at the start (a re-used
    slot): RMSprop's mean square at its initial value, Adam's moments at 0 (Adam's bias
    correction follows the shared step count, so those rows' first steps are smaller than a
    fresh Adam's)."""
    if hasattr(optimizer, "square_avg"):
        optimizer.square_avg[index][rows] = optimizer.initial
    else:
        optimizer.exp_avg[index][rows] = 0.0
        optimizer.exp_avg_sq[index][rows] = 0.0


AGENT = Agent(
    script="future_work/" + os.path.basename(__file__),  # checkpoints name it so
    Args=Args,
    make_env=make_env,
    network=ActorCritic,
    network_args=NETWORK_ARGS,
    worker=worker,
)


def main() -> int:
    """Train (a3c_runtime.a3c.train), or play a checkpoint's episodes with --evaluate; see
    --help for every flag."""
    return run(AGENT)


if __name__ == "__main__":
    raise SystemExit(main())
