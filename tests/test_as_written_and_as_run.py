"""docs/as-written-and-as-run.md's table is data: each row names the text's form, the form the
thesis's runs computed, which of the two is the default, and the flag that gives the other. Every
flag in the table must parse against a script and change its Args, and every row has a check here
that the default computes the form the row says and the flag the other (a row without its check,
or a check without its row, fails). Life loss as terminal, a choice
the text leaves open, is checked last."""

from __future__ import annotations

import ast
import contextlib
import dataclasses
import io
import math
import os
import re
import shlex

import a3c_runtime as runtime
import numpy as np
import pytest
import torch
import tyro
from conftest import ALL_SCRIPTS, ROOT, SCRIPT_PATHS, SCRIPTS, load_script

PAGE = ROOT / "docs" / "as-written-and-as-run.md"
COLUMNS = ["what", "the text", "as run", "default", "thesis results made with the as-run form"]


def table() -> list[dict[str, str]]:
    """The page's table, one dict per row keyed by COLUMNS (an escaped \\| is a cell's text)."""
    lines = PAGE.read_text().splitlines()
    header = next(i for i, line in enumerate(lines) if line.startswith("| what |"))
    cells = lambda line: [c.strip() for c in re.split(r"(?<!\\)\|", line)[1:-1]]  # noqa: E731
    assert cells(lines[header]) == COLUMNS
    rows = []
    for line in lines[header + 2 :]:
        if not line.startswith("|"):
            break
        rows.append(dict(zip(COLUMNS, cells(line), strict=True)))
    return rows


ROWS = table()


def flags_in(cell: str) -> list[list[str]]:
    """The command-line flags a cell names: each backticked span that starts with --."""
    return [shlex.split(span) for span in re.findall(r"`(--[^`]+)`", cell)]


def field_of(flag: str) -> str:
    name = flag.removeprefix("--").replace("-", "_")
    return name.removeprefix("no_")


def parse(argv: list[str]) -> tuple[str, object]:
    """(script, Args) of the first script whose Args has argv's flag and parses argv."""
    for name in ALL_SCRIPTS:
        module = load_script(name)
        fields = {f.name for f in dataclasses.fields(module.Args)}
        if field_of(argv[0]) not in fields:
            continue
        with contextlib.redirect_stderr(io.StringIO()) as err:
            try:
                return name, tyro.cli(module.Args, args=argv)
            except SystemExit:
                pytest.fail(f"{shlex.join(argv)} does not parse for {name}: {err.getvalue()}")
    pytest.fail(f"no script has the flag {argv[0]}")


def test_the_table_has_every_row_and_each_row_a_flag_for_its_other_form():
    assert len(ROWS) >= 14
    for row in ROWS:
        default = row["default"]
        assert default in ("text", "as run") or default.startswith("neither"), row["what"]
        # the form that is not the default: the as-run column, the text's, or (neither) the flag
        # that gives the text's and the runs' form, named in the default column
        other = {"text": "as run", "as run": "the text"}.get(default, "default")
        assert flags_in(row[other]), f"{row['what']}: no flag for its {other} form"
        assert row["thesis results made with the as-run form"], row["what"]


@pytest.mark.parametrize("row", ROWS, ids=[row["what"] for row in ROWS])
def test_each_flag_parses_and_the_other_forms_flag_changes_the_default(row):
    other = {"text": "as run", "as run": "the text"}.get(row["default"], "default")
    for column in ("the text", "as run", "default"):
        for argv in flags_in(row[column]):
            script, args = parse(argv)
            defaults = load_script(script).Args()
            changed = {f for f in vars(args) if getattr(args, f) != getattr(defaults, f)}
            if column == other:
                assert changed, f"{shlex.join(argv)} ({script}) leaves every flag at its default"
            assert changed <= {field_of(a) for a in argv if a.startswith("--")}


# ---- the rows whose default is not the text: the default computes the runs' form -------------


def check_value_loss() -> None:
    """The default is lambda_V * 0.5 (G - V)^2 (today's formula, bit for bit, in every script);
    --value-loss-form text is lambda_V (G - V)^2, twice the value gradient."""
    generator = torch.Generator().manual_seed(0)
    log_probs = torch.randn(7, 3, generator=generator).log_softmax(-1)
    values = torch.randn(7, generator=generator)
    returns = torch.randn(7, generator=generator)
    actions = torch.tensor([0, 1, 2, 2, 1, 0, 1])
    for name in ALL_SCRIPTS:
        module = load_script(name)
        assert module.Args().value_loss_form == "code"
        assert tyro.cli(module.Args, args=["--value-loss-form", "text"]).value_loss_form == "text"
        grads = {}
        for form in ("code", "text"):
            v = values.clone().requires_grad_()
            loss, _, value_loss, _ = module.a3c_loss(
                log_probs, actions, v, returns, 0.01, 0.5, form
            )
            grads[form] = torch.autograd.grad(loss, v)[0]
            advantages = returns - v.detach()
            policy = -(log_probs.gather(1, actions[:, None]).squeeze(1) * advantages).sum()
            entropy = -(log_probs.exp() * log_probs).sum()
            if form == "code":  # the formula of the scripts before the flag, bit for bit
                expected = 0.5 * advantages.pow(2).sum()
                assert torch.equal(value_loss.detach(), expected)
                assert torch.equal(loss.detach(), policy - 0.01 * entropy + 0.5 * expected)
            else:
                torch.testing.assert_close(value_loss.detach(), advantages.pow(2).sum())
        torch.testing.assert_close(grads["code"], 0.5 * (values - returns))
        torch.testing.assert_close(grads["text"], 2 * grads["code"])
        # and the worker hands the flag to the loss
        for call in calls(name, "a3c_loss"):
            assert "args.value_loss_form" in ast.unparse(call), f"{name}: {ast.unparse(call)}"


def check_clipping() -> None:
    """The default clips each tensor by its norm at 40; --grad-clip-mode value clips each element
    at 40 (section 6.3.1)."""
    args = runtime.resolve_defaults(load_script("a3c_ff").Args(num_workers=1))
    assert (args.grad_clip_mode, args.grad_clip) == ("norm", 40.0)
    value = parse(["--grad-clip-mode", "value"])[1]
    assert runtime.resolve_defaults(value).grad_clip == 40.0
    big, small = torch.tensor([30.0, -50.0, 40.0]), torch.tensor([3.0, -4.0])
    by_norm = [big.clone(), small.clone()]
    runtime.clip_gradients(by_norm, "norm", 40.0)
    torch.testing.assert_close(by_norm[0], big * 40.0 / big.norm())  # its direction kept
    assert torch.equal(by_norm[1], small)  # under the bound: untouched
    by_value = [big.clone(), small.clone()]
    runtime.clip_gradients(by_value, "value", 40.0)
    assert by_value[0].tolist() == [30.0, -40.0, 40.0] and torch.equal(by_value[1], small)


def check_learning_rate() -> None:
    """The default anneals 7e-4 linearly to 0 at T_max; --no-anneal-lr keeps Table 5.1's eta."""
    args = runtime.resolve_defaults(load_script("a3c_ff").Args(num_workers=1))
    half = args.total_timesteps // 2
    assert runtime.annealed_lr(args, half) == pytest.approx(7e-4 / 2)
    constant = runtime.resolve_defaults(parse(["--no-anneal-lr"])[1])
    assert runtime.annealed_lr(constant, half) == 7e-4


def check_workers() -> None:
    """The default is a worker per core; --num-workers 12 gives the thesis's 12."""
    assert load_script("a3c_ff").Args().num_workers == len(os.sched_getaffinity(0))
    assert parse(["--num-workers", "12"])[1].num_workers == 12


NOT_THE_TEXT = {
    "A3C's value loss": check_value_loss,
    "gradient clipping": check_clipping,
    "learning-rate schedule": check_learning_rate,
    "actor-learners": check_workers,
}


def test_each_row_whose_default_is_not_the_text_has_its_check():
    assert {row["what"] for row in ROWS if row["default"] != "text"} == set(NOT_THE_TEXT)


@pytest.mark.parametrize("what", NOT_THE_TEXT)
def test_the_default_computes_the_runs_form_and_the_flag_the_texts(what):
    NOT_THE_TEXT[what]()


# ---- the rows whose default is the text: the flag computes the runs' form ----------------------


def network(script: str, *argv: str) -> torch.nn.Module:
    args = runtime.resolve_defaults(
        tyro.cli(load_script(script).Args, args=[*argv, "--num-workers", "1"])
    )
    return load_script(script).AGENT.build_network(3, args)


def check_mu_form() -> None:
    """Eq. 7.7's mu by default; --mu-form code: tau (d_- / (d_i + d_-) - d_i)."""
    glpq = load_script("a3c_glpq")
    assert glpq.Args().mu_form == "text"
    distances = torch.rand(2, 3, 4, generator=torch.Generator().manual_seed(0)) * 5
    d_minus = glpq.nearest_other_action(distances)
    tau = 1.3
    for form, scores in (
        ("text", (d_minus - distances) / (d_minus + distances)),
        ("code", d_minus / (distances + d_minus) - distances),
    ):
        expected = (tau * scores).logsumexp(-1).log_softmax(-1)
        torch.testing.assert_close(glpq.glpq_log_policy(distances, tau, 4, form), expected)
    assert parse(["--mu-form", "code"])[1].mu_form == "code"


def check_tau_loss_scope() -> None:
    """1/tau times the policy-gradient term by default; as run, the entropy bonus too."""
    glpq = load_script("a3c_glpq")
    policy, entropy, value, scale = torch.tensor(2.0), torch.tensor(3.0), torch.tensor(5.0), 0.25
    for scope, expected in (
        ("policy", scale * policy - 0.01 * entropy + value),
        ("policy-and-entropy", scale * (policy - 0.01 * entropy) + value),
    ):
        args = tyro.cli(glpq.Args, args=["--tau-loss-scope", scope])
        loss = glpq.tau_corrected_loss(
            policy - 0.01 * entropy + value, policy, entropy, scale, args
        )
        torch.testing.assert_close(loss, expected)


def check_tau_parametrization() -> None:
    """A trainable tau is log tau by default, tau itself with --tau-parametrization plain; both
    start at the cold tau for p0, 1.445 on Catch's 3 actions."""
    log = network("a3c_glpq", "--temperature", "trainable")
    plain = network("a3c_glpq", "--temperature", "trainable", "--tau-parametrization", "plain")
    assert log.log_tau.exp().item() == pytest.approx(1.445, abs=1e-3)
    assert plain.plain_tau.item() == pytest.approx(1.445, abs=1e-3) and not hasattr(
        plain, "log_tau"
    )


def conv_shapes(model: torch.nn.Module) -> list[tuple]:
    convs = [m for m in model.modules() if isinstance(m, torch.nn.Conv2d)]
    return [(m.kernel_size[0], m.stride[0]) for m in convs]


def check_conv_layout() -> None:
    """SS and WW: A3C FF's 8x8/4, 4x4/2 by default; --conv-layout final: 5x5/3, 3x3/2."""
    for script in ("a3c_ss", "a3c_ww"):
        assert conv_shapes(network(script)) == [(8, 4), (4, 2)]
        assert conv_shapes(network(script, "--conv-layout", "final")) == [(5, 3), (3, 2)]


def check_ss_temperature() -> None:
    """A trainable tau per map by default, in SS and WW; one global (--ss-temperature global),
    fixed (--no-ss-trainable-temperature) as the runs' labels had them; WW's global tau as run."""
    for script, maps in (("a3c_ss", 64), ("a3c_ww", 32)):
        temperatures = dict(network(script).named_parameters())
        (name,) = [n for n in temperatures if n.endswith("temperature")]
        assert temperatures[name].numel() == maps
    fixed = network("a3c_ss", "--ss-temperature", "global", "--no-ss-trainable-temperature")
    assert not [n for n, _ in fixed.named_parameters() if n.endswith("temperature")]
    (buffer,) = [b for n, b in fixed.named_buffers() if n.endswith("temperature")]
    assert buffer.numel() == 1
    ww = dict(network("a3c_ww", "--ss-temperature", "global").named_parameters())
    assert [p.numel() for n, p in ww.items() if n.endswith("temperature")] == [1]


def check_lws() -> None:
    """Eq. 6.2's one Sigma per layer and 'valid' padding by default; as run, a 2x2 A per
    centroid and 'same' padding (the second layer's grid 11x11, not 9x9), and "LWS S"'s 2x2 grid
    of centroids."""
    text = network("a3c_lws")
    run = network("a3c_lws", "--lws-similarity", "matrix", "--lws-padding", "same")
    sigmas = [p for n, p in text.named_parameters() if n.endswith("sigma")]
    matrices = [p for n, p in run.named_parameters() if n.endswith("matrix")]
    assert [s.shape for s in sigmas] == [(2, 2), (2, 2)]
    assert len(matrices) == 2 and all(m.shape[-2:] == (2, 2) and m.dim() == 4 for m in matrices)
    for model, grid in ((text, 9), (run, 11)):
        linear = next(m for m in model.modules() if isinstance(m, torch.nn.Linear))
        assert linear.in_features == 64 * grid * grid
    grid = network("a3c_lws", "--lws-centroid-init", "grid", "--lws-kcps", "4")
    centroids = next(c for n, c in grid.named_parameters() if n.endswith("centroids"))
    assert sorted({round(x, 4) for x in centroids.flatten().tolist()}) == [0.3333, 0.6667]


def check_global_norm() -> None:
    """Global-norm clipping at c_g = 25 by default, 21.3796 as run: the gradients' global norm
    scaled to the bound."""
    for argv, bound in (([], 25.0), (["--grad-clip", "21.3796"], 21.3796)):
        args = runtime.resolve_defaults(parse(["--grad-clip-mode", "global-norm", *argv])[1])
        assert args.grad_clip == bound
        grads = [torch.full((3,), 20.0), torch.full((4,), 10.0)]
        runtime.clip_gradients(grads, args.grad_clip_mode, args.grad_clip)
        norm = torch.linalg.vector_norm(torch.cat(grads)).item()
        assert norm == pytest.approx(bound, rel=1e-5)


def check_adam_beta2() -> None:
    """Adam's beta2 0.99 by default, 0.999 with --adam-beta2 0.999."""
    from a3c_runtime.hogwild import make_optimizer

    params = [torch.zeros(2)]
    for argv, beta2 in (([], 0.99), (["--adam-beta2", "0.999"], 0.999)):
        args = parse(["--optimizer", "adam", *argv])[1]
        assert make_optimizer(params, args).beta2 == beta2


def check_weight_init() -> None:
    """--weight-init he: a normal of std sqrt(2 / fan_in) truncated at 2 std (6.3.3's);
    variance-scaling, TensorFlow's as run: std sqrt(2.6 / fan_in) truncated, He's variance."""
    for argv, variance in ((["--weight-init", "he"], 0.774 * 2), (["--weight-init",
                           "variance-scaling"], 0.774 * 2.6)):  # fmt: skip
        torch.manual_seed(0)
        model = network("a3c_ff", *argv)
        for layer in (model.torso[2], model.torso[5]):  # conv 4x4 and the FC layer
            fan_in = layer.weight[0].numel()
            assert layer.weight.var().item() == pytest.approx(variance / fan_in, rel=0.05)
            assert torch.all(layer.bias == 0)


def check_adam_epsilon() -> None:
    """Eq. A.5's eps by default; --adam-epsilon-form code, the thesis code's update
    lr sqrt(1 - beta2^t) / (1 - beta1^t) m / sqrt(v + eps), over two steps."""
    from a3c_runtime.hogwild import make_optimizer

    lr, eps, beta1, beta2 = 0.1, 0.1, 0.9, 0.999
    for argv, form in (([], "text"), (["--adam-epsilon-form", "code"], "code")):
        args = parse(["--optimizer", "adam", "--adam-beta2", "0.999", *argv])[1]
        param = torch.tensor([1.0])
        optimizer = make_optimizer([param], args)
        expected, m, v = 1.0, 0.0, 0.0
        for t, g in ((1, 2.0), (2, -1.0)):
            optimizer.step([torch.tensor([g])], lr=lr)
            m, v = beta1 * m + (1 - beta1) * g, beta2 * v + (1 - beta2) * g * g
            m_hat, v_hat = m / (1 - beta1**t), v / (1 - beta2**t)
            if form == "text":
                expected -= lr * m_hat / math.sqrt(v_hat + eps)
            else:
                expected -= lr * math.sqrt(1 - beta2**t) / (1 - beta1**t) * m / math.sqrt(v + eps)
            assert param.item() == pytest.approx(expected, rel=1e-6), (form, t)


def check_vf_coef() -> None:
    """lambda_V 0.5 by default; --vf-coef 1.0 doubles the value loss's part of the loss."""
    ff = load_script("a3c_ff")
    assert ff.Args().vf_coef == 0.5
    log_probs = torch.full((2, 3), 1 / 3).log()
    values, returns, actions = (
        torch.tensor([0.0, 1.0]),
        torch.tensor([2.0, 0.0]),
        torch.tensor([0, 1]),
    )
    half = ff.a3c_loss(log_probs, actions, values, returns, 0.0, 0.5)
    whole = ff.a3c_loss(
        log_probs, actions, values, returns, 0.0, parse(["--vf-coef", "1.0"])[1].vf_coef
    )
    torch.testing.assert_close(whole[0] - whole[1], 2 * (half[0] - half[1]))


THE_TEXT = {
    "GLPQ's relative distance": check_mu_form,
    "GLPQ's 1/tau loss correction": check_tau_loss_scope,
    "GLPQ's trainable tau": check_tau_parametrization,
    "SS and WW convolutions": check_conv_layout,
    "SS and WW temperatures": check_ss_temperature,
    "LWS layers": check_lws,
    "global-norm clipping bound": check_global_norm,
    "He initialisation": check_weight_init,
    "Adam's beta2": check_adam_beta2,
    "Adam's epsilon": check_adam_epsilon,
    "value loss factor": check_vf_coef,
}


def test_each_row_whose_default_is_the_text_has_its_check():
    assert {row["what"] for row in ROWS if row["default"] == "text"} == set(THE_TEXT)


@pytest.mark.parametrize("what", THE_TEXT)
def test_the_default_computes_the_texts_form_and_the_flag_the_runs(what):
    THE_TEXT[what]()


def calls(script: str, function: str) -> list[ast.Call]:
    """The calls of `function` inside the script's worker function(s)."""
    tree = ast.parse(SCRIPT_PATHS[script].read_text())
    return [
        node
        for worker in tree.body
        if isinstance(worker, ast.FunctionDef) and worker.name == "worker"
        for node in ast.walk(worker)
        if isinstance(node, ast.Call) and ast.unparse(node.func) == function
    ]


# ---- life loss as terminal: off (the runs), one flag on ---------------------------------------


def first_ending(terminal_on_life_loss: bool) -> tuple[int, bool]:
    """(step, whether the game is over) of the first ended episode of Breakout's one env of the
    worker's vector env, on a fixed sequence of random actions."""
    envs = load_script("a3c_ff").make_vector_env("BreakoutNoFrameskip-v4", 1, terminal_on_life_loss)
    try:
        envs.reset(seed=0)
        actions = np.random.default_rng(0).integers(0, 4, 2000)
        for step, action in enumerate(actions):
            _, _, terminated, truncated, info = envs.step(np.array([action]))
            if terminated[0] or truncated[0]:
                return step, bool(info["final_info"]["_episode"][0])
    finally:
        envs.close()
    pytest.fail("no episode ended in 2000 steps")


def test_terminal_on_life_loss_ends_the_learners_episode_at_a_lost_life():
    pytest.importorskip("ale_py")
    for name in SCRIPTS:
        module = load_script(name)
        assert module.Args().terminal_on_life_loss is False
        assert tyro.cli(module.Args, args=["--terminal-on-life-loss"]).terminal_on_life_loss
    for name in ALL_SCRIPTS:  # every worker makes its envs with the flag
        (call,) = calls(name, "make_vector_env")
        assert "args.terminal_on_life_loss" in ast.unparse(call), name
    game_over_step, game_over = first_ending(False)
    life_step, life_game_over = first_ending(True)
    assert game_over  # by default an episode is a whole game, as in the thesis's runs
    assert not life_game_over and life_step < game_over_step  # a life, the game goes on


def test_terminal_on_life_loss_needs_an_ale_id():
    args = tyro.cli(load_script("a3c_ff").Args, args=["--terminal-on-life-loss"])
    with pytest.raises(runtime.UsageError, match="--terminal-on-life-loss needs an ALE id"):
        runtime.resolve_defaults(args)
