# A3C LWS with online centroids: chapter 8's "the local weight sharing might be made online much
# like an attention mechanism ... a component of the network that predicts the appropriate
# centroid location given some input". A small network (CentroidPredictor) predicts each LWS
# layer's centroids from the frames, per sample. A copy of a3c_lws.py: only the network differs.
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

    # Local weight sharing (thesis 6.1)
    lws_kcps: int = 3
    """S, the kernel-centroid pairs per LWS layer"""
    lws_centroids: Literal["feature", "group"] = "feature"
    """feature-wise: a centroid per pair and output map; group-wise: one per pair (kernel group)"""
    lws_trainable: bool = True
    """train the centroids and Sigma (or A_s) by gradient descent; else they stay at their
    initial values"""
    lws_similarity: Literal["sigma", "matrix"] = "sigma"
    """sigma: S_s = exp(-(x - mu_s)^T Sigma (x - mu_s)), one 2x2 Sigma per layer (eq. 6.2);
    matrix (as run): S_s = exp(-||A_s (x - mu_s)||^2), a 2x2 A_s per centroid; both start at
    the identity"""
    lws_padding: Literal["valid", "same"] = "valid"
    """valid: grids 84 -> 20 -> 9 (the thesis's parameter count, 6.1.2); same (as run):
    TensorFlow's, 84 -> 21 -> 11"""
    lws_second_layer_maps: int = 64
    """the second LWS layer's output maps (thesis 6.1.2: 64; the Figure 6.3 LWS runs used 32)"""
    lws_kernel_init: Literal["default", "uniform-sqrt3"] = "default"
    """the LWS kernels' init: default = --weight-init and --bias-init, like the other layers;
    uniform-sqrt3 (as run) = U(+-sqrt(3 / fan_in)) with zero biases, other layers unchanged"""
    lws_centroid_init: Literal["uniform", "grid"] = "uniform"
    """uniform: U[0, 1]^2 (thesis 6.1.2); grid: an n x n grid, n = sqrt(S), at k / (n + 1) on
    each axis (1/3 and 2/3 for S = 4), as the thesis code placed them for "LWS S" (Figure 6.3:
    --lws-kcps 4 --lws-centroids group --no-lws-trainable)"""

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
# args a checkpoint's network depends on; seed too, since fixed centroids are drawn from it
NETWORK_ARGS = ("env", "activation", "scale_obs", "lws_kcps", "lws_centroids", "lws_trainable",
                "lws_similarity", "lws_padding", "lws_second_layer_maps", "lws_centroid_init",
                "seed")  # fmt: skip


class LWSConv2d(nn.Module):
    """Local weight sharing layer (thesis 6.1.1, eqs. 6.1 and 6.2), before its activation:
    Y = sum_s (W_s * X + b_s) * S_s / sum_s' S_s', with the similarity of output cell x = (i, j)
    (row, column; the output grid spans [0, 1] on both axes) to centroid mu_s
    S_s = exp(-(x - mu_s)^T Sigma (x - mu_s)) with one 2x2 Sigma per layer (eq. 6.2), or, as run
    (--lws-similarity matrix), S_s = exp(-||A_s (x - mu_s)||^2) with a 2x2 A_s per centroid.
    Feature-wise: a centroid per pair and output map; group-wise: one per pair (its kernel
    group). Centroids start U[0, 1] or on a grid, Sigma and A_s at the identity; fixed ones are
    buffers made with `generator`, so that every process, seeded alike, builds the same.
    Padding valid, or TensorFlow's same: ceil(in / stride) outputs, the odd padding pixel at the
    bottom and right."""

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int, stride: int,
                 input_size: int, args: Args, generator: torch.Generator):  # fmt: skip
        super().__init__()
        self.kcps, self.out_channels = args.lws_kcps, out_channels
        # the S kernels as one convolution with S times the output maps: one pass, not S
        self.conv = nn.Conv2d(in_channels, self.kcps * out_channels, kernel_size, stride)
        self.padding: tuple[int, int, int, int] | None = None
        if args.lws_padding == "same":
            self.size = -(-input_size // stride)
            total = max((self.size - 1) * stride + kernel_size - input_size, 0)
            # F.pad (left, right, top, bottom): Conv2d's own padding is symmetric, TF's is not
            self.padding = (total // 2, total - total // 2) * 2
        else:
            self.size = (input_size - kernel_size) // stride + 1
        # the output grid's row (i) and column (j) coordinates
        self.register_buffer("axis", torch.linspace(0.0, 1.0, self.size), persistent=False)
        maps = out_channels if args.lws_centroids == "feature" else 1
        if args.lws_centroid_init == "grid":  # as the thesis code placed them: k / (n + 1)
            n = math.isqrt(self.kcps)
            ticks = torch.arange(1, n + 1) / (n + 1)
            grid = torch.cartesian_prod(ticks, ticks)  # (S, 2), pair p at row p // n, column p % n
            centroids = grid[:, None].repeat(1, maps, 1)
        else:
            centroids = torch.rand(self.kcps, maps, 2, generator=generator)
        # Sigma: one per layer; A_s: one per centroid, shaped like the centroids
        self.metric_name = "sigma" if args.lws_similarity == "sigma" else "matrix"
        shape = () if self.metric_name == "sigma" else (self.kcps, maps)
        metric = torch.eye(2).repeat(*shape, 1, 1)
        self.cached_for: tuple[torch.Tensor, torch.Tensor] | None = None  # see similarity_weights
        # the predicted centroids of the batch, set by the network before each pass; the static
        # centroids (a buffer) only give the predictor its starting point
        self.sample_centroids: torch.Tensor | None = None
        self.register_buffer("centroids", centroids)
        if args.lws_trainable:
            self.register_parameter(self.metric_name, nn.Parameter(metric))
        else:
            self.register_buffer(self.metric_name, metric)

    def metric(self) -> torch.Tensor:
        """Sigma (2, 2) or the A_s (S, maps, 2, 2)."""
        return getattr(self, self.metric_name)

    def similarity_weights(self) -> torch.Tensor:
        """S_s / sum_s' S_s' as (H, W, S, maps): the conv output's channels_last order, or
        (B, H, W, S, maps) with online centroids. At every output cell they sum to 1 over s."""
        if self.sample_centroids is not None:
            return self.compute_similarity_weights(self.sample_centroids)
        if torch.is_grad_enabled():
            return self.compute_similarity_weights()
        # acting: the centroids and Sigma (or A_s) change once per rollout (the sync), not per
        # step, so reuse the weights while both equal those they were computed from
        cached_for, metric = self.cached_for, self.metric()
        if cached_for is None or not (
            torch.equal(cached_for[0], self.centroids) and torch.equal(cached_for[1], metric)
        ):
            self.cached_for = (self.centroids.clone(), metric.clone())
            self.cached_weights = self.compute_similarity_weights()
        return self.cached_weights

    def compute_similarity_weights(self, centroids: torch.Tensor | None = None) -> torch.Tensor:
        """The weights for the centroids (S, maps, 2), or per sample (B, S, maps, 2), by
        default the layer's own."""
        centroids = self.centroids if centroids is None else centroids
        centroid_rows, centroid_cols = centroids.unbind(-1)  # i_s, j_s: ([B,] S, maps) each
        axis = self.axis[:, None, None]
        rows = (axis - centroid_rows[..., None, :, :])[..., None, :, :]  # ([B,] H, 1, S, maps)
        cols = (axis - centroid_cols[..., None, :, :])[..., None, :, :, :]  # ([B,] 1, W, S, maps)
        # d^T Q d, expanded: 7x faster than an einsum over (H, W, S, m, 2)
        if self.metric_name == "sigma":
            (q00, q01), (q10, q11) = self.sigma  # Q = Sigma
        else:  # ||A_s d||^2 = d^T A_s^T A_s d
            (a00, a01), (a10, a11) = self.matrix.permute(2, 3, 0, 1)  # each (S, maps)
            q00, q11 = a00 * a00 + a10 * a10, a01 * a01 + a11 * a11
            q01 = q10 = a00 * a01 + a10 * a11
        distance = q00 * rows.square() + (q01 + q10) * rows * cols + q11 * cols.square()
        # exp(-d_s) / sum_s' exp(-d_s') is a softmax over s; softmax cannot overflow
        return torch.softmax(-distance, dim=-2)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.padding is not None:
            x = F.pad(x, self.padding)  # keeps channels_last
        # the S convolutions' outputs as (B, H, W, S, C): a view of the channels_last output
        y = self.conv(x).permute(0, 2, 3, 1).unflatten(3, (self.kcps, self.out_channels))
        return (y * self.similarity_weights()).sum(3).permute(0, 3, 1, 2)  # (B, C, H, W)


class CentroidPredictor(nn.Module):
    """Online centroids (thesis chapter 8: "a component of the network that predicts the
    appropriate centroid location given some input"): from the frames (B, 4, 84, 84) in [0, 1], each
    LWS layer's centroids (B, S, maps, 2) in (0, 1), as sigmoid(W z + b) of a small encoder's z:
    4x4 average pooling (84 -> 21), conv 16 5x5/2 (-> 9), FC 64, ReLUs. Each head starts with
    W = 0 and b = logit of its layer's static centroids, so that every sample's centroids begin
    where the static ones would, and the value and policy losses move them per input."""

    def __init__(self, layers: list[LWSConv2d], hidden: int = 64):
        super().__init__()
        self.encoder = nn.Sequential(
            nn.AvgPool2d(4),
            nn.Conv2d(4, 16, 5, stride=2),
            nn.ReLU(inplace=True),
            nn.Flatten(),
            nn.Linear(16 * 9 * 9, hidden),
            nn.ReLU(inplace=True),
        )
        self.shapes = [tuple(layer.centroids.shape) for layer in layers]  # (S, maps, 2) each
        self.heads = nn.ModuleList(nn.Linear(hidden, math.prod(shape)) for shape in self.shapes)
        self.starts = [layer.centroids.detach().clamp(0.02, 0.98) for layer in layers]

    def reset_heads(self) -> None:
        """W = 0, b = logit(static centroids): after the network's weight initialisation."""
        with torch.no_grad():
            for head, start in zip(self.heads, self.starts, strict=True):
                head.weight.zero_()
                head.bias.copy_(torch.logit(start).flatten())

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        z = self.encoder(x)
        return [
            torch.sigmoid(head(z)).view(len(x), *shape)
            for head, shape in zip(self.heads, self.shapes, strict=True)
        ]


class ActorCritic(nn.Module):
    """A3C LWS (thesis 6.1.2): A3C FF with both convolutions replaced by LWS layers: LWS 32 8x8/4,
    LWS 64 4x4/2, FC 256, softmax policy, linear value. The defaults follow the text; the
    Figure 6.3 LWS runs were, as run (thesis-notes.md "As run"): --lws-similarity matrix
    --lws-padding same --lws-second-layer-maps 32 --lws-kernel-init uniform-sqrt3 (FC input
    11 * 11 * 32), "LWS S" also --lws-kcps 4 --lws-centroid-init grid --lws-centroids group
    --no-lws-trainable.

    Parameters with the defaults (S = 3, A actions): 3 * (8*8*4*32 + 4*4*32*64) = 122,880 kernel
    weights, 288 kernel biases (b_s of eq. 6.1), FC 5184*256 + 256, policy 256*A + A, value 257;
    in all 1,450,785 + 257 A, plus the centroids (feature-wise 3 * (32 + 64) * 2 = 576,
    group-wise 3 * 2 * 2 = 12) and Sigma (2 * 4 = 8) when trainable (A_s instead of Sigma:
    4 per centroid, feature-wise 1,152, group-wise 24). The thesis's 1,449,984 + 256 A
    (6.1.2) counts weights only: 122,880 + 1,327,104 + 256 A; adding the 288 + 256 + A + 257
    biases and value head gives ours. A3C FF here has 1,368,673 + 257 A (weights only:
    1,368,064 + 256 A); the thesis's 1,336,320 + 256 A for it is 31,744 = 4*4*64*31 lower, as if
    the second kernel's input depth of 32 had been left out (4*4*64 instead of 4*4*32*64)."""

    def __init__(self, num_actions: int, args: Args):
        super().__init__()
        if args.lws_kcps < 1:
            raise UsageError(f"--lws-kcps must be >= 1 (got {args.lws_kcps})")
        maps = args.lws_second_layer_maps
        if maps < 1:
            raise UsageError(f"--lws-second-layer-maps must be >= 1 (got {maps})")
        if args.lws_centroid_init == "grid" and math.isqrt(args.lws_kcps) ** 2 != args.lws_kcps:
            raise UsageError(
                f"--lws-centroid-init grid needs a square --lws-kcps: 1, 4, 9, ... "
                f"(got {args.lws_kcps})"
            )
        activation = {"relu": nn.ReLU, "elu": nn.ELU}[args.activation]
        generator = torch.Generator().manual_seed(args.seed)
        first = LWSConv2d(4, 32, 8, 4, input_size=84, args=args, generator=generator)
        second = LWSConv2d(32, maps, 4, 2, input_size=first.size, args=args, generator=generator)
        self.torso = nn.Sequential(  # in-place activations: fewer allocations, same gradients
            first,
            activation(inplace=True),
            second,
            activation(inplace=True),
            nn.Flatten(),
            nn.Linear(maps * second.size * second.size, 256),
            activation(inplace=True),
        )
        self.policy = nn.Linear(256, num_actions)
        self.value = nn.Linear(256, 1)
        self.obs_scale = 1.0 / 255.0 if args.scale_obs else 1.0
        init_parameters(self, args.weight_init, args.bias_init)
        if args.lws_kernel_init == "uniform-sqrt3":  # as run: tflearn's uniform_scaling, bias 0
            for layer in (first, second):
                init_parameters(layer.conv, "uniform-sqrt3", 0.0)
        self.lws_layers = [first, second]
        self.centroid_predictor = CentroidPredictor(self.lws_layers)
        init_parameters(self.centroid_predictor, args.weight_init, args.bias_init)
        self.centroid_predictor.reset_heads()

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # channels_last makes oneDNN's convolution backward about 2x faster on CPU
        x = obs.to(dtype=torch.float32, memory_format=torch.channels_last)
        # this batch's centroids, per sample; the predictor sees frames in [0, 1] whatever
        # --scale-obs: unscaled Catch frames would saturate its sigmoids once its heads learn
        predicted = self.centroid_predictor(x * (1.0 / 255.0))
        for layer, centroids in zip(self.lws_layers, predicted, strict=True):
            layer.sample_centroids = centroids
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
