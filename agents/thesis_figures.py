"""Every thesis Catch figure as one command: its lines as the thesis's code ran them, swept, drawn.

The thesis's Catch figures (6.3, 6.5-6.8, 7.1-7.3, 7.5-7.7, A.1-A.3, C.1) are learning-rate
sweeps. For each figure this tool runs every line with the flags that reproduce its configuration
as run (read from the thesis's own code: docs/thesis-figures-as-run.md and the "As run" section
of docs/thesis-notes.md), through agents/sweep.py, at a budget of your choosing, and draws the
figure with agents/plot_sweep.py, next to the thesis's numbers where they are known.

    python agents/thesis_figures.py --list                  # every figure, its lines and flags
    python agents/thesis_figures.py fig7.6 --runs 8 --steps 250000 --out sweeps/thesis
    python agents/thesis_figures.py fig6.6 fig6.7 --runs 50 --steps 1000000 --num-workers 12 \\
        --lr-range 1e-6:1e-2 --out sweeps/thesis          # the thesis's own budget
    python agents/thesis_figures.py all --runs 8 --steps 250000 --out sweeps/thesis --dry-run

For each line of figure FIG it runs

    python agents/sweep.py agents/SCRIPT --out OUT/FIG/LINE --runs N --total-timesteps S \\
        --seed SEED --sample learning-rate=loguniform:LOW:HIGH [the line's samples] \\
        -- [the line's flags] --eval-interval S/20 [--num-workers W]

then `python agents/plot_sweep.py OUT/FIG/*/results.csv --labels ... --out OUT/FIG/FIG.png`
(figures that sweep a second flag, A.1 and C.1, get a second plot against it) and writes
OUT/FIG/FIG.md: the plot's table, the thesis's statement and the lines' notes.

Budget. Evaluations come every S/20 steps, 20 per run as in the thesis (50,000 in 1M), so that a
run's score, the mean of its final 5 evaluations, covers its last 20% of training (see
results/sweep_catch/reproduce.sh). The defaults (learning rates log-uniform in [1e-5, 1e-2], the
range the thesis's bars average over; sweep seed 1; one worker per run) are those of the first
reproduction, results/sweep_catch/, so run i of every line gets the same learning rate and seed as
its run i. The thesis ran 50-100 learning rates in [1e-6, 1e-2] per line, 1M steps, 12 workers.

Resuming. sweep.py resumes: the same command again skips the runs already in each line's
results.csv, and a larger --runs extends them. --round K runs the lines in rounds of K more runs
each (as reproduce.sh does), so that a stopped figure has covered its lines evenly. A line that
appears in several figures (A3C FF) is run once per figure, in that figure's folder.

Exit codes: 0 when done, 1 when some line's every run failed, 2 for bad arguments (nothing is
created) or a sweep folder holding another configuration, 130 when interrupted.
"""

from __future__ import annotations

import argparse
import math
import os
import shlex
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
AGENTS = ROOT / "agents"
SWEEP = AGENTS / "sweep.py"
PLOT = AGENTS / "plot_sweep.py"
DEFAULT_LR_RANGE = (1e-5, 1e-2)  # the range the thesis's bars average over
EVALUATIONS_PER_RUN = 20  # the thesis: every 50,000 steps in 1M
DEFAULT_SEED = 1  # sweep.py's default, and the first reproduction's
THESIS_BUDGET = "thesis: 50-100 lrs in [1e-6, 1e-2], 1M steps, 12 workers"


@dataclass(frozen=True)
class Line:
    """One line of a thesis figure: an agent script and the flags that reproduce it as run."""

    slug: str  # its folder under OUT/FIG
    label: str  # as in the thesis figure
    script: str  # in agents/
    flags: str  # fixed flags, as run (shell words)
    source: str  # the preset and the as-run doc's evidence; (I) marks an inference
    samples: tuple[str, ...] = ()  # sampled jointly with the learning rate: NAME=DIST
    approximation: str = ""  # why these flags are only the nearest to what ran, if they are

    @property
    def argv(self) -> list[str]:
        return shlex.split(self.flags)

    def sample_names(self) -> list[str]:
        return [sample.partition("=")[0] for sample in self.samples]


@dataclass(frozen=True)
class Plot:
    """One plot of a figure: the score against a swept flag."""

    x: str = "learning-rate"
    bar_range: tuple[float, float] | None = None  # None: plot_sweep.py's, [1e-5, 1e-2]
    suffix: str = ""  # OUT/FIG/FIG{suffix}.png


@dataclass(frozen=True)
class Figure:
    id: str
    caption: str  # a summary of the thesis's caption
    thesis: str  # what the thesis reports: its numbers, or its qualitative statement
    lines: tuple[Line, ...]
    numbers: tuple[tuple[str, float], ...] = ()  # label -> the thesis's bar value
    plots: tuple[Plot, ...] = (Plot(),)
    note: str = ""

    @property
    def number(self) -> str:
        return self.id.removeprefix("fig")


# ------------------------------------------------------------------------------------------------
# The figures, as run. Presets are experiments/param_sweep.py's in jostosh/deeprl; every preset
# up to 69 most likely ran lambda_V = 1.0 (--vf-coef 1.0), later ones 0.5 (thesis-figures-as-run
# .md). Every run: 12 threads, RMSprop (decay 0.99, eps 0.1 in the root), per-tensor norm-40
# clipping, torch init, ReLU, beta 0.01 unless a line says otherwise.
# ------------------------------------------------------------------------------------------------
FF = "a3c_ff.py"
# A3C FF as run (preset 13); lambda_V 1.0 (I): the text's 0.5 became the default on 2017-05-22
FF_AS_RUN = "--vf-coef 1.0"
FF_SOURCE = "preset 13 (PS@53e5759); lambda_V 1.0 (I)"
# LWS as run (sisws.py@42815b8): exp(-||A (x - mu)||^2) with a trainable 2x2 A per centroid,
# 'same' padding, 32 maps in both layers, tflearn uniform_scaling kernels U(+-sqrt(3/fan_in))
LWS_AS_RUN = (
    "--lws-similarity matrix --lws-padding same --lws-second-layer-maps 32 "
    "--lws-kernel-init uniform-sqrt3 --vf-coef 1.0"
)
# LPQ as run: p0 = pN = 0.787 gives tau = 1 by the cold formula, which a3c_lpq.py computes
LPQ_AS_RUN = "--prototypes-per-action 16 --vf-coef 0.5"
# GLPQ as run: the code's relative distance (an operator-precedence slip), squared Euclidean
GLPQ_AS_RUN = "--mu-form code --distance squared-euclidean --vf-coef 0.5"
# the 1/tau loss correction as run divided the entropy term too
CORRECTED = "--tau-loss-correction --tau-loss-scope policy-and-entropy"
GLPQ_COLD = f"--temperature cold {CORRECTED} {GLPQ_AS_RUN}"
GLPQ_HOT = f"--temperature hot {CORRECTED} {GLPQ_AS_RUN}"
C1_SOURCE = (
    "preset 89 (lpq_temp.sh): GLPQ, ppa = nwp = 16, a constant tau ~ logU[0.01, 100] (lpq_temp, "
    "7fe0c47 to aab9541, before any loss correction) (I)"
)
COLD_SOURCE = "GLPQ, cold tau(t), p 0.9 -> 0.99 (tau 1.445 -> 2.644), pi_loss_correct, beta 0.01"


def ff_line(slug: str = "a3c-ff", label: str = "A3C FF", extra: str = "") -> Line:
    """The A3C FF baseline of a figure (preset 13), with the flag the figure varies spelled out."""
    return Line(slug, label, FF, f"{FF_AS_RUN} {extra}".strip(), FF_SOURCE)


def lpq(slug: str, label: str, distance: str, source: str, approximation: str = "") -> Line:
    """An LPQ line of Figure 7.1 or 7.7: 16 prototypes per action, all competing, tau = 1."""
    source += ": LPQ, ppa = nwp = 16, p0 = pN = 0.787 so tau = 1, no loss correction"
    flags = f"--distance {distance} {LPQ_AS_RUN}"
    return Line(slug, label, "a3c_lpq.py", flags, source, approximation=approximation)


def glpq(slug: str, label: str, flags: str, source: str, **more) -> Line:
    """A GLPQ line (as run, every one: --mu-form code)."""
    return Line(slug, label, "a3c_glpq.py", flags, source, **more)


FIGURES: tuple[Figure, ...] = (
    Figure(
        "fig6.3",
        "Local weight sharing (A3C LWS) against the default A3C FF",
        "LWS is comparable to A3C FF, and for learning rates above 1e-3 slightly better "
        "(more robust to high learning rates).",
        (
            ff_line("default", "Default"),
            Line(
                "lws-t",
                "LWS T",
                "a3c_lws.py",
                "--lws-kcps 3 --lws-centroids feature --lws-trainable --lws-centroid-init uniform "
                f"{LWS_AS_RUN}",
                "preset 21 (a3c_sisws, NN/SW@42815b8): 3 KCPs per layer, centroids U[0,1]^2 and "
                "Sigma = I, both trainable, feature-wise; the label is read as LWS+T+FW (I); "
                "lambda_V 1.0 (I)",
            ),
            Line(
                "lws-s",
                "LWS S",
                "a3c_lws.py",
                "--lws-kcps 4 --lws-centroid-init grid --lws-centroids group --no-lws-trainable "
                f"{LWS_AS_RUN}",
                "preset 22 (a3c_sisws_s, SW@42815b8): a fixed 2x2 grid of KCPs, group-wise; "
                "lambda_V 1.0 (I)",
            ),
        ),
        note="lws.sh's alternative lines LWS PF 48 / PF 64 / PF 64 M (presets 115-117: "
        "group-wise, 64 second-layer maps, Mahalanobis) are not included; which set the thesis "
        "figure shows is not recorded.",
    ),
    Figure(
        "fig6.5",
        "Spatial softmax (A3C SS) and what-and-where (A3C WW) against A3C FF",
        "WW beats the other architectures except A3C FF, and is marginally worse than FF above "
        "lr 1e-3; A3C SS TT beats A3C SS GT TT (read in the text as per-map against global "
        "temperatures; as run, a fixed global tau against trainable per-map taus).",
        (
            ff_line(),
            Line(
                "ss",
                "A3C SS",
                "a3c_ss.py",
                "--conv-layout ff --ss-temperature global --ss-trainable-temperature "
                "--ss-initial-temperature 0.6 --vf-coef 0.5",
                "preset 118 (a3c_ff_ss): one scalar trainable tau, init 0.6; conv 8x8/4, 4x4/2 "
                "if run 06-24 to 06-28, else 5x5/3, 3x3/2 (--conv-layout final) (I)",
            ),
            Line(
                "ss-tt",
                "A3C SS TT",
                "a3c_ss.py",
                "--conv-layout ff --ss-temperature global --no-ss-trainable-temperature "
                "--ss-initial-temperature 0.6 --vf-coef 0.5",
                "preset 120: trainable_temp False, i.e. one fixed tau = 0.6 (the label "
                "contradicts the code)",
            ),
            Line(
                "ss-gt-tt",
                "A3C SS GT TT",
                "a3c_ss.py",
                "--conv-layout ff --ss-temperature per-map --ss-trainable-temperature "
                "--ss-initial-temperature 0.6 --vf-coef 0.5",
                "preset 121: ss_temp_global True, passed as temp_pf, i.e. a trainable tau per "
                "map (the flag is inverted, L/NN@31ec590)",
            ),
            Line(
                "ww",
                "A3C WW",
                "a3c_ww.py",
                "--conv-layout ff --ss-temperature global --ss-trainable-temperature "
                "--ss-initial-temperature 0.6 --vf-coef 0.5",
                "preset 119 (a3c_ff_ww): 32 ReLU + 32 spatial-softmax maps, one scalar "
                "trainable tau, init 0.6; conv layout as for SS (I)",
            ),
        ),
        note="SS's ss_epsilon 0.5 (in the as-run doc) has no flag here. The conv layout is an "
        "inference from the dates: --conv-layout final for the thesis code's final network.",
    ),
    Figure(
        "fig6.6",
        "Gradient clipping: clip by value against global norm clipping",
        "Clipping by value outperforms global norm clipping, mainly at lower learning rates.",
        (
            # "by value" as run: tf.clip_by_norm(grad, 40) per tensor, our --grad-clip-mode norm
            ff_line("clip-by-value", "Clip by value", "--grad-clip-mode norm --grad-clip 40"),
            Line(
                "global-norm",
                "Global norm clipping",
                FF,
                f"{FF_AS_RUN} --grad-clip-mode global-norm --grad-clip 21.3796",
                "preset 31 (PS@6420f72): c_g = 21.3796, where the text says 25; lambda_V 1.0 (I)",
            ),
        ),
    ),
    Figure(
        "fig6.7",
        "ELU against the default ReLU in A3C FF",
        "ELU is worse than ReLU, mainly for learning rates above 1e-3.",
        (
            ff_line("relu", "ReLU", "--activation relu"),
            Line(
                "elu",
                "ELU",
                FF,
                f"{FF_AS_RUN} --activation elu",
                "preset 4 (PS@5385cc5): ELU in all hidden layers; lambda_V 1.0 (I)",
            ),
        ),
    ),
    Figure(
        "fig6.8",
        "Weight initializations in A3C FF",
        "The default (torch) initialization is best, substantially so in the mean over all "
        "evaluations.",
        (
            # the thesis labels the torch init U(+-1/sqrt(fan_in)) "Glorot & Bengio"
            ff_line("glorot-bengio", "Glorot & Bengio", "--weight-init torch"),
            Line(
                "he",
                "He et al.",
                FF,
                f"{FF_AS_RUN} --weight-init he --bias-init 0",
                "preset 42 (L@9342f15): variance_scaling_initializer() in all layers, zero "
                "biases; lambda_V 1.0 (I)",
                approximation="TF's variance_scaling_initializer() (truncated normal, fan-in) "
                "as our --weight-init he: truncated normal std sqrt(2/fan_in); TF's exact "
                "scale and truncation correction may differ",
            ),
            Line(
                "sussillo-abbott",
                "Sussillo & Abbott",
                FF,
                f"{FF_AS_RUN} --weight-init uniform-sqrt3 --bias-init 0",
                "preset 66 (L@cfbcd6f): tflearn conv uniform_scaling, FC truncated_normal, zero "
                "biases; lambda_V 1.0 (I)",
                approximation="the FC layers ran tflearn's truncated_normal (its default std "
                "0.02), approximated by uniform-sqrt3 like the convolutions",
            ),
        ),
    ),
    Figure(
        "fig7.1",
        "LPQ with different distance functions (16 prototypes per action, all competing)",
        "Squared Euclidean is clearly best, followed by Manhattan; the others are considerably "
        "worse.",
        (
            lpq("pearson", "Pearson", "pearson", "preset 96 (PS@7e344e2)"),
            lpq("cosine", "Cosine", "cosine", "preset 97 (PS@7e344e2)"),
            lpq("manhattan", "Manhattan", "manhattan", "preset 98 (PS@7e344e2)"),
            lpq("euclidean", "Euclidean", "euclidean", "preset 99 (PS@7e344e2)"),
            lpq(
                "squared-euclidean",
                "Squared Euclidean",
                "squared-euclidean",
                "preset 100 (PS@7e344e2)",
            ),
            lpq(
                "inverse-squared-euclidean",
                "Inverse Euclidean squared",
                "inverse-squared-euclidean",
                "preset 140 (inv_euc_sq, added in 95d250d, after c8e4a6c)",
                approximation="as run 1/(0.001 + d^2) with the hot tau of about 2.58 (I); "
                "a3c_lpq.py computes the text's -1/(1 + d^2) with tau = 1",
            ),
        ),
        note="The caption names A3C FF, but the figure's launch script (presets 96-100) has no "
        "A3C FF preset; none is run here.",
    ),
    Figure(
        "fig7.2",
        "GLPQ with 16, 32 or 64 prototypes per action against A3C FF",
        "64 prototypes per action deteriorate performance; 16 and 32 are comparable.",
        (
            ff_line(),
            glpq(
                "ppa-32",
                "|W|/|A| = 32",
                f"{GLPQ_COLD} --prototypes-per-action 32",
                f"preset 112 (PS@3e7ef86): {COLD_SOURCE}",
            ),
            glpq(
                "ppa-64",
                "|W|/|A| = 64",
                f"{GLPQ_COLD} --prototypes-per-action 64",
                f"preset 113 (PS@3e7ef86): {COLD_SOURCE}",
            ),
            glpq(
                "ppa-16",
                "|W|/|A| = 16",
                f"{GLPQ_COLD} --prototypes-per-action 16",
                f"preset 94 (PS@bba4954): {COLD_SOURCE}",
            ),
        ),
    ),
    Figure(
        "fig7.3",
        "GLPQ with competition sizes k = 4, 8, 16 (16 prototypes per action) against A3C FF",
        "Roughly invariant to the competition size; in general greater k is best.",
        (
            ff_line(),
            glpq(
                "k-8",
                "k=8",
                f"{GLPQ_COLD} --prototypes-per-action 16 --competition-size 8",
                "preset 107 (PS@f91d5a1): as preset 94, the 8 nearest per action compete",
            ),
            glpq(
                "k-4",
                "k=4",
                f"{GLPQ_COLD} --prototypes-per-action 16 --competition-size 4",
                "preset 108 (PS@f91d5a1): as preset 94, the 4 nearest per action compete",
            ),
            glpq(
                "k-16",
                "k=16",
                f"{GLPQ_COLD} --prototypes-per-action 16",
                f"preset 94 (PS@bba4954): {COLD_SOURCE}",
            ),
        ),
    ),
    Figure(
        "fig7.5",
        "GLPQ temperature configurations: tau = 1, tau(t), tau(t) with L_pi(tau), trainable",
        "tau(t) alone is worse than tau = 1 or tau(t) with the 1/tau loss correction; with the "
        "correction it ends marginally above tau = 1; the trainable tau used the correction too.",
        (
            glpq(
                "tau-1",
                "tau = 1",
                "--temperature fixed --tau 1 --no-tau-loss-correction --prototypes-per-action 15 "
                f"--competition-size 10 {GLPQ_AS_RUN}",
                "preset 86 (96ea994): 15 prototypes per action, the 10 nearest competing; older "
                "than any temperature code, so tau = 1 (I); no loss correction",
            ),
            glpq(
                "tau-t",
                "tau(t)",
                # beta = 0, which the text does not mention
                "--temperature cold --no-tau-loss-correction --ent-coef 0 "
                f"--prototypes-per-action 16 {GLPQ_AS_RUN}",
                "preset 93 (PS@aab9541): cold p 0.9 -> 0.99, beta = 0, no loss correction",
            ),
            glpq(
                "tau-t-corrected",
                "tau(t), L_pi(tau)",
                f"{GLPQ_COLD} --prototypes-per-action 16",
                f"preset 94 (PS@bba4954): {COLD_SOURCE}",
            ),
            glpq(
                "tau-trainable",
                "tau trainable",
                f"--temperature trainable --tau 1.445 --tau-parametrization plain {CORRECTED} "
                f"--prototypes-per-action 16 {GLPQ_AS_RUN}",
                "preset 106: a plain variable tau initialised at 0.5 ln(2 * 0.9 / 0.1) = 1.445, "
                "pi_loss_correct",
            ),
        ),
    ),
    Figure(
        "fig7.6",
        "GLPQ temperature schedules cold, hot and searing against A3C FF",
        "Bars (mean final-5 score over lr in [1e-5, 1e-2], 1M steps, 12 workers): A3C FF 0.73, "
        "GLPQ hot 0.78, cold 0.77, searing 0.81; hot and searing are best below lr 10^-3.5.",
        (
            ff_line(),
            glpq(
                "glpq-hot",
                "GLPQ hot",
                f"{GLPQ_HOT} --prototypes-per-action 16",
                "preset 126 (PS@160314f): lpq_hot, tau = 0.5 ln(p (16 * 3 - 1) / (1 - p)), "
                "p 0.9 -> 0.99 (3.02 -> 4.22), pi_loss_correct",
            ),
            glpq(
                "glpq-cold",
                "GLPQ cold",
                f"{GLPQ_COLD} --prototypes-per-action 16",
                f"preset 94 (PS@bba4954): {COLD_SOURCE}",
            ),
            glpq(
                "glpq-searing",
                "GLPQ searing",
                f"--temperature searing {CORRECTED} {GLPQ_AS_RUN} --prototypes-per-action 16",
                "preset 131 (PS@a0f958e): hot with p 0.95 -> 0.999 (3.40 -> 5.38), pi_loss_correct",
            ),
        ),
        numbers=(("A3C FF", 0.73), ("GLPQ hot", 0.78), ("GLPQ cold", 0.77), ("GLPQ searing", 0.81)),
    ),
    Figure(
        "fig7.7",
        "GLPQ (hot) against LPQ, both squared Euclidean, 16 prototypes per action, all competing",
        "GLPQ beats LPQ marginally but consistently, most at the extremes of the learning rate.",
        (
            glpq(
                "glpq",
                "GLPQ",
                f"{GLPQ_HOT} --prototypes-per-action 16",
                "preset 126 (hot), as in Figure 7.6",
            ),
            lpq("lpq", "LPQ", "squared-euclidean", "preset 100 (PS@7e344e2), as in Figure 7.1"),
        ),
    ),
    Figure(
        "figA.1",
        "Global norm clipping bound c_g and learning rate, sampled jointly (A3C FF)",
        "Only a small area of the search space gives good results; c_g = 25 (about 10^1.4) was "
        "chosen from it.",
        (
            Line(
                "global-norm",
                "Global norm clipping",
                FF,
                f"{FF_AS_RUN} --grad-clip-mode global-norm",
                "preset 12 (PS): global_clipping with c_g ~ logU[0.5, 40] (upper bound 2.0 "
                "before aa67475); lambda_V 1.0 (I)",
                samples=("grad-clip=loguniform:0.5:40",),
            ),
        ),
        plots=(Plot(), Plot("grad-clip", (0.5, 40.0), "-grad-clip")),
        note="The thesis's plot is 2-D (c_g against lr); here the score against each of them.",
    ),
    Figure(
        "figA.2",
        "RMSprop against Adam (A3C FF)",
        "RMSprop outperforms Adam substantially.",
        (
            ff_line("rmsprop", "RMSprop", "--optimizer rmsprop"),
            Line(
                "adam",
                "Adam",
                FF,
                f"{FF_AS_RUN} --optimizer adam --adam-beta1 0.9 --adam-beta2 0.999 --optim-eps 0.1",
                "preset 10: shared Adam, beta1 0.9, beta2 0.999 (the text says 0.99), eps inside "
                "the root, same norm-40 clipping; lambda_V 1.0 (I)",
                approximation="eps inside the root was 1e-8 for runs launched before 2017-03-09 "
                "and 0.1 after (I); this line uses 0.1 (--optim-eps 1e-8 for the other)",
            ),
        ),
    ),
    Figure(
        "figA.3",
        "Bias initialization: 'Torch' against a constant 0.01 (A3C FF)",
        "No significant improvement from biases at 0.01.",
        (
            # both presets ran He weights (I): the bias is what the figure varies
            Line(
                "torch",
                "Torch",
                FF,
                f"{FF_AS_RUN} --weight-init he --bias-init 0",
                "preset 42, the He-init preset of Figure 6.8 (contradicts the 'Torch' label): "
                "He weights, zero biases; lambda_V 1.0 (I)",
                approximation="He init as in Figure 6.8 (TF's variance_scaling_initializer() as "
                "our --weight-init he)",
            ),
            Line(
                "bias-0.01",
                "xi = 0.01",
                FF,
                f"{FF_AS_RUN} --weight-init he --bias-init 0.01",
                "preset 55 (PS@e818f1a, 05-06): plain a3c_ff right after all biases became "
                "0.01; weights were He until 05-09, torch after (I); lambda_V 1.0 (I)",
                approximation="the weights are an inference from dates (He until 05-09, then "
                "torch: --weight-init torch --bias-init 0.01)",
            ),
        ),
    ),
    Figure(
        "figC.1",
        "Temperature sweep of 'the default LPQ' (as run: GLPQ with a fixed tau)",
        "No statement beyond the caption: the lines are prototype initializations, random "
        "uniform and zero clipping.",
        (
            glpq(
                "random-uniform",
                "Random uniform",
                f"--temperature fixed --no-tau-loss-correction {GLPQ_AS_RUN} "
                "--prototypes-per-action 16 --prototype-init uniform",
                C1_SOURCE,
                samples=("tau=loguniform:0.01:100",),
            ),
            glpq(
                "zero-clipping",
                "Zero clipping",
                f"--temperature fixed --no-tau-loss-correction {GLPQ_AS_RUN} "
                "--prototypes-per-action 16 --prototype-init uniform-clipped",
                C1_SOURCE,
                samples=("tau=loguniform:0.01:100",),
                approximation="no as-run script has a 'zero clipping' line; U(+-1/16) with "
                "negatives set to 0 is our reading. The candidate preset 138 (beta 0, "
                "relu(truncated normal) prototypes, loss correction, tau ~ U[1, 256]) has no "
                "flag for its prototype init",
            ),
        ),
        plots=(Plot(), Plot("tau", (0.01, 100.0), "-tau")),
        note="The thesis plots the score against tau; the learning rate is sampled as well.",
    ),
)
FIGURE_IDS = tuple(figure.id for figure in FIGURES)
BY_ID = {figure.id: figure for figure in FIGURES}


# ------------------------------------------------------------------------------------------------
# Commands
# ------------------------------------------------------------------------------------------------
def figure_id(text: str) -> str | None:
    """The figure id for fig7.6, Fig7.6, 7.6, figa.1, A.1 ...; None when there is no such figure."""
    key = text.strip().lower()
    for prefix in ("figure", "fig"):
        if key.startswith(prefix):
            key = key[len(prefix) :].lstrip(" ._-")
            break
    key = f"fig{key.upper()}"
    return key if key in BY_ID else None


def display(path: Path) -> str:
    """A path as the commands show it: relative to the working directory when inside it."""
    relative = os.path.relpath(path)
    return relative if not relative.startswith("..") else str(path)


def sweep_command(figure: Figure, line: Line, options: argparse.Namespace, runs: int) -> list[str]:
    """The sweep.py command of one line (without the interpreter)."""
    low, high = options.lr_range
    command = [
        display(SWEEP),
        display(AGENTS / line.script),
        "--out",
        str(Path(options.out) / figure.id / line.slug),
        "--runs",
        str(runs),
        "--total-timesteps",
        str(options.steps),
        "--seed",
        str(options.seed),
        "--sample",  # first, so that run i draws the first reproduction's learning rate
        f"learning-rate=loguniform:{low:g}:{high:g}",
    ]
    for sample in line.samples:
        command += ["--sample", sample]
    command += ["--backend", options.backend]
    for flag, value in (
        ("--address", options.address),
        ("--cpus", options.cpus),
        ("--max-concurrent", options.max_concurrent),
    ):
        if value is not None:
            command += [flag, str(value)]
    command += ["--", *line.argv, "--eval-interval", str(eval_interval(options.steps))]
    if options.num_workers is not None:
        command += ["--num-workers", str(options.num_workers)]
    return command


def plural(count: int, noun: str) -> str:
    return f"{count} {noun}{'s' * (count != 1)}"


def eval_interval(steps: int) -> int:
    return max(1, steps // EVALUATIONS_PER_RUN)


def plot_commands(figure: Figure, options: argparse.Namespace) -> list[tuple[list[str], Path]]:
    """plot_sweep.py's commands (without the interpreter) and the PNG each writes."""
    folder = Path(options.out) / figure.id
    tables = [str(folder / line.slug / "results.csv") for line in figure.lines]
    low, high = options.lr_range
    workers = options.num_workers or 1
    title = (
        f"Thesis Figure {figure.number} as run: {plural(options.runs, 'run')} per line, lr in "
        f"[{low:g}, {high:g}], {options.steps:,} steps, {plural(workers, 'worker')} "
        f"({THESIS_BUDGET})"
    )
    commands = []
    for plot in figure.plots:
        png = folder / f"{figure.id}{plot.suffix}.png"
        command = [display(PLOT), *tables, "--labels", *(line.label for line in figure.lines)]
        command += ["--out", str(png), "--title", title]
        if plot.x != "learning-rate":
            command += ["--x", plot.x]
        if plot.bar_range is not None:
            command += ["--bar-range", *(f"{v:g}" for v in plot.bar_range)]
        for label, value in figure.numbers:
            command += ["--reference", f"{label}={value:g}"]
        commands.append((command, png))
    return commands


def execute(command: list[str], capture: bool = False) -> tuple[int, str]:
    """Run a tool of this folder with this interpreter: its exit code, and its stdout when
    captured (echoed all the same). A Ctrl-C reaches the tool too (same process group): this
    waits for it to stop its runs cleanly (sweep.py exits 130) rather than killing it."""
    if capture:
        result = subprocess.run([sys.executable, *command], stdout=subprocess.PIPE, text=True)
        sys.stdout.write(result.stdout)
        sys.stdout.flush()
        return result.returncode, result.stdout
    sys.stdout.flush()
    process = subprocess.Popen([sys.executable, *command])
    while True:
        try:
            return process.wait(), ""
        except KeyboardInterrupt:
            continue


def run_figures(figures: list[Figure], options: argparse.Namespace) -> int:
    """Sweep every line of the figures (in rounds of --round runs), then draw each figure."""
    step = options.round or options.runs
    failed = []
    for target in [*range(step, options.runs, step), options.runs]:
        for figure in figures:
            for line in figure.lines:
                print(f"== {figure.id} {line.label}: {plural(target, 'run')}", flush=True)
                code, _ = execute(sweep_command(figure, line, options, target))
                if code in (2, 130):  # a folder with another sweep, or interrupted: stop here
                    return code
                if code == 1 and target == options.runs:
                    failed.append(f"{figure.id} {line.label}")
    for figure in figures:
        draw(figure, options)
    if failed:
        print(f"every run failed: {', '.join(failed)}", file=sys.stderr)
        return 1
    return 0


def draw(figure: Figure, options: argparse.Namespace) -> None:
    """Plot a figure's lines and write OUT/FIG/FIG.md: the tables, the thesis, the notes."""
    folder = Path(options.out) / figure.id
    missing = [
        line.label for line in figure.lines if not (folder / line.slug / "results.csv").exists()
    ]
    if missing:
        print(f"{figure.id}: no results for {', '.join(missing)}; not plotted", file=sys.stderr)
        return
    tables = []
    for command, png in plot_commands(figure, options):
        code, stdout = execute(command, capture=True)
        if code == 0:
            table = [row for row in stdout.splitlines() if not row.startswith("wrote ")]
            tables.append(f"![{figure.id}]({png.name})\n\n" + "\n".join(table))
    summary = [
        f"# Thesis Figure {figure.number}, as run: {figure.caption}",
        "",
        f"Command: `{shlex.join(['python', display(Path(__file__)), *options.argv])}`",
        "",
        *tables,
        "",
        f"Thesis: {figure.thesis}",
        "",
        "Lines:",
        *(f"- {line.label}: `{line.script} {line.flags}` ({line.source})" for line in figure.lines),
        *approximations(figure),
    ]
    if figure.note:
        summary += ["", f"Note: {figure.note}"]
    (folder / f"{figure.id}.md").write_text("\n".join(summary) + "\n")


def approximations(figure: Figure) -> list[str]:
    notes = [f"- {line.label}: {line.approximation}" for line in figure.lines if line.approximation]
    return ["", "Not exactly as run:", *notes] if notes else []


# ------------------------------------------------------------------------------------------------
# Command line
# ------------------------------------------------------------------------------------------------
def list_figures(figures: list[Figure]) -> str:
    """Every figure, its lines with their full flags, and the notes."""
    out = []
    for figure in figures:
        out += [f"{figure.id}  {figure.caption}", f"  thesis: {figure.thesis}"]
        if figure.note:
            out.append(f"  note: {figure.note}")
        for line in figure.lines:
            samples = "".join(f" --sample {sample}" for sample in line.samples)
            out.append(f"  - {line.label} [{line.slug}]: {line.script} {line.flags}{samples}")
            out.append(f"      as run: {line.source}")
            if line.approximation:
                out.append(f"      NOT EXACT: {line.approximation}")
        out.append("")
    inexact = [
        f"  {figure.id} {line.label}: {line.approximation}"
        for figure in figures
        for line in figure.lines
        if line.approximation
    ]
    if inexact:
        out += ["Lines whose flags are the nearest to what ran, not exactly it:", *inexact, ""]
    out.append(
        "Every line also gets --eval-interval STEPS/20 (and --num-workers W when given); the "
        "learning rate is sampled log-uniform in --lr-range."
    )
    return "\n".join(out)


class Parser(argparse.ArgumentParser):
    def error(self, message: str):
        """One line, exit 2 (argparse's own error prints the usage too)."""
        print(f"{self.prog}: error: {message} (see --help)", file=sys.stderr)
        raise SystemExit(2)


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def lr_range(text: str) -> tuple[float, float]:
    try:
        low, high = (float(v) for v in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected LOW:HIGH, got {text!r}") from None
    if not (math.isfinite(high) and 0 < low < high):
        raise argparse.ArgumentTypeError(f"need 0 < LOW < HIGH, got {text!r}")
    return low, high


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = Parser(
        prog="thesis_figures.py",
        description="Run a thesis Catch figure's lines as run, through agents/sweep.py, and draw "
        "it with agents/plot_sweep.py. See the module docstring for more.",
    )
    parser.add_argument(
        "figures", nargs="*", metavar="FIG", help=f"figure ids ({', '.join(FIGURE_IDS)}) or all"
    )
    parser.add_argument("--list", action="store_true", help="print the figures, lines and flags")
    parser.add_argument(
        "--dry-run", action="store_true", help="print the sweep and plot commands, run nothing"
    )
    parser.add_argument("--out", default=None, help="the output folder (gets OUT/FIG/LINE)")
    parser.add_argument("--runs", type=positive_int, default=None, help="learning rates per line")
    parser.add_argument("--steps", type=positive_int, default=None, help="steps per run")
    parser.add_argument(
        "--lr-range",
        type=lr_range,
        default=DEFAULT_LR_RANGE,
        metavar="LOW:HIGH",
        help="learning rates log-uniform in [LOW, HIGH] (default 1e-5:1e-2; the thesis 1e-6:1e-2)",
    )
    parser.add_argument(
        "--seed", type=int, default=DEFAULT_SEED, help="the sweep seed (default 1, as sweep.py)"
    )
    parser.add_argument(
        "--num-workers",
        type=positive_int,
        default=None,
        help="workers per run (default: sweep.py's 1; the thesis ran 12)",
    )
    parser.add_argument(
        "--round",
        type=positive_int,
        default=None,
        metavar="K",
        help="run the lines in rounds of K more runs each (default: all runs of a line at once)",
    )
    parser.add_argument("--backend", choices=["local", "ray"], default="local")
    parser.add_argument("--address", default=None, help="with --backend ray: a running cluster")
    parser.add_argument("--cpus", type=positive_int, default=None, help="passed to sweep.py")
    parser.add_argument(
        "--max-concurrent", type=positive_int, default=None, help="passed to sweep.py"
    )
    options = parser.parse_args(argv)
    options.argv = list(argv)
    ids = []
    for text in options.figures:
        if text.lower() == "all":
            ids += FIGURE_IDS
            continue
        found = figure_id(text)
        if found is None:
            parser.error(f"unknown figure {text!r}; valid: {', '.join(FIGURE_IDS)}, all")
        ids.append(found)
    options.ids = list(dict.fromkeys(ids))
    if not options.list:
        if not options.ids:
            parser.error(f"name a figure: {', '.join(FIGURE_IDS)}, all (or --list)")
        missing = [flag for flag in ("out", "runs", "steps") if getattr(options, flag) is None]
        if missing:
            parser.error(
                "the following arguments are required: " + ", ".join(f"--{m}" for m in missing)
            )
        if options.address and options.backend != "ray":
            parser.error("--address needs --backend ray")
    return options


def main(argv: list[str] | None = None) -> int:
    options = parse_args(sys.argv[1:] if argv is None else argv)
    figures = [BY_ID[i] for i in options.ids] if options.ids else list(FIGURES)
    if options.list:
        print(list_figures(figures))
        return 0
    if options.dry_run:
        for figure in figures:
            print(f"# {figure.id}: {figure.caption}")
            for line in figure.lines:
                print(shlex.join(["python", *sweep_command(figure, line, options, options.runs)]))
            for command, _ in plot_commands(figure, options):
                print(shlex.join(["python", *command]))
        return 0
    return run_figures(figures, options)


if __name__ == "__main__":
    sys.exit(main())
