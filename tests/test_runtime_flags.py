"""a3c_runtime.flags: env-dependent defaults, --precision, --help, and bad flags: one line,
exit 2, nothing created."""

import re
import warnings

import a3c_runtime as runtime
import pytest
import torch
from conftest import (
    ALL_SCRIPTS,
    SCRIPT_PATHS,
    load_script,
    main_exit,
    run_into_a_closed_pipe,
)

import catch_env  # noqa: F401  (registers Catch-v0)


def test_defaults_and_validation():
    a3c = load_script("a3c_ff")
    catch = runtime.resolve_defaults(a3c.Args())
    assert (catch.total_timesteps, catch.eval_interval, catch.scale_obs) == (10**6, 50_000, False)
    assert catch.grad_clip == 40.0 and catch.learning_rate == 7e-4 and catch.eval_episodes == 50
    assert runtime.resolve_defaults(a3c.Args(grad_clip_mode="global-norm")).grad_clip == 25.0
    atari = runtime.resolve_defaults(a3c.Args(env="BreakoutNoFrameskip-v4"))
    assert (atari.total_timesteps, atari.eval_interval, atari.scale_obs) == (10**8, 10**6, True)
    # a checkpoint at every evaluation unless told otherwise, on either kind of env
    assert (catch.checkpoint_interval, atari.checkpoint_interval) == (50_000, 10**6)
    given = runtime.resolve_defaults(a3c.Args(eval_interval=7000))
    assert given.checkpoint_interval == 7000
    assert runtime.resolve_defaults(a3c.Args(checkpoint_interval=300)).checkpoint_interval == 300
    with pytest.raises(runtime.UsageError, match="--gamma must be in"):
        runtime.resolve_defaults(a3c.Args(gamma=1.5))
    with pytest.raises(runtime.UsageError, match="unknown --env"):
        runtime.resolve_defaults(a3c.Args(env="Nope-v0"))


BAD_FLAGS = [
    (["--t-max", "0"], "error: --t-max must be >= 1 (got 0)"),
    (["--learning-rate", "nan"], "error: --learning-rate must be >= 0"),
    (["--env", "Nope-v0"], "error: unknown --env 'Nope-v0'; valid: Catch-v0"),
    (["--env", "CartPole-v1"], "error: --env CartPole-v1 gives no stacked 84x84 frames; valid: "),
    (["--resume", "/nonexistent/checkpoint.pt"], "error: checkpoint '/nonexistent/checkpoint.pt' "),
    (["--evaluate", "/nonexistent/checkpoint.pt"], "error: checkpoint '/nonexistent/"),
    (["--grad-clip-mode", "sideways"], "norm"),
    (["--rms-init", "-1"], "error: --rms-init must be >= 0 (got -1.0)"),
    (["--resume", "."], "error: checkpoint '.' is a folder, and holds no checkpoint.pt"),
    (["--exp-name", "my/run"], "error: --exp-name 'my/run' holds a path separator: it is one "),
    # a run's flags within what its checkpoints may hold (a3c_runtime.flags.Flags)
    (
        ["--eval-episodes", "10001"],
        "error: --eval-episodes must be less than or equal to 10000 "
        "(got 10001): the most a checkpoint holds",
    ),
    (["--num-workers", "1025"], "error: --num-workers must be less than or equal to 1024"),
    (["--t-max", "100001"], "error: --t-max must be less than or equal to 100000 (got 100001)"),
    # the rollout buffers alone: 10^7 x 89 frames of 84x84 bytes, 6 TiB
    (
        ["--envs-per-worker", "10000000", "--num-workers", "1"],
        "error: --envs-per-worker 10,000,000 x --num-workers 1 needs at least 6.",
    ),
]


def test_the_memory_check_counts_every_workers_every_envs_frames(monkeypatch):
    """(t_max + 1) x K stacked frames per worker, and per env its stack and the vector env's
    frames, times the workers (before the command-line refusals below, which a wrong bound
    would let through to a run of millions of envs): 3 workers x 1,000 envs at --t-max 5 is
    refused where 1 MB is available, with the bytes it needs; 1 x 1 fits."""
    from a3c_runtime.flags import check_memory

    import catch_env.catch as catch

    monkeypatch.setattr(catch, "available_memory", lambda: 10**6)
    per_env = (4 * 6 + 4 + catch.VECTOR_FRAMES_PER_ENV) * 84 * 84
    with pytest.raises(runtime.UsageError) as raised:
        check_memory(3, 1000, 5)
    needed = catch.format_bytes(3 * 1000 * per_env)
    assert str(raised.value).startswith(
        f"--envs-per-worker 1,000 x --num-workers 3 needs at least {needed} (the rollout buffers"
    ), raised.value
    check_memory(1, 1, 5)  # (per_env bytes: under 1 MB)
    assert per_env < 10**6


@pytest.mark.parametrize(("flags", "message"), BAD_FLAGS, ids=lambda v: " ".join(v)[:24])
def test_bad_flags_exit_2_with_one_line_and_create_nothing(
    flags, message, tmp_path, monkeypatch, capsys
):
    """The runtime's checks, the same code path for every script (each script's own flag
    checks are the next test's)."""
    monkeypatch.chdir(tmp_path)  # the default runs_root is ./runs
    code, err = main_exit(load_script("a3c_ff"), flags, monkeypatch, capsys)
    assert code == 2
    if message.startswith("error: "):
        assert err.startswith(message) and err.count("\n") == 1, err
    else:  # tyro's box around a Literal's choices
        assert message in err
    assert list(tmp_path.iterdir()) == []


VARIANT_FLAG_ERRORS = {
    "a3c_lws": ["--lws-kcps", "0"],
    "a3c_ss": ["--ss-initial-temperature", "0"],
    "a3c_ww": ["--ww-where-maps", "65"],
    "a3c_lstm": ["--lstm-cells", "0"],
    "a3c_lpq": ["--competition-size", "17"],
    "a3c_glpq": ["--temperature", "hot", "--p-end", "1"],
}


@pytest.mark.parametrize("name", VARIANT_FLAG_ERRORS)  # one of each script's own checks
def test_bad_variant_flags_are_refused_before_the_run_folder_exists(
    name, tmp_path, monkeypatch, capsys
):
    monkeypatch.chdir(tmp_path)
    code, err = main_exit(load_script(name), VARIANT_FLAG_ERRORS[name], monkeypatch, capsys)
    assert code == 2 and err.startswith("error: ") and err.count("\n") == 1, err
    assert list(tmp_path.iterdir()) == []


def test_autocast_contexts_need_a_resolved_precision():
    with pytest.raises(ValueError, match="unresolved --precision 'auto'"):
        runtime.autocast_contexts("auto")


@pytest.mark.parametrize("k", [1, 4])
def test_auto_precision_is_fp32_at_k1_on_every_cpu_and_bf16_for_batches_where_native(
    k, monkeypatch, capsys
):
    """The default run (K = 1, the thesis's algorithm) is the same float32 computation on every
    CPU; only the fast setting's batches (K > 1) compute in bf16, and only where it is native."""
    a3c = load_script("a3c_ff")
    monkeypatch.setattr(runtime.flags, "native_bf16", lambda: True)
    resolved = runtime.resolve_defaults(a3c.Args(envs_per_worker=k)).precision
    assert resolved == ("fp32" if k == 1 else "bf16")
    assert runtime.resolve_defaults(a3c.Args()).precision == "fp32"  # the default command
    act, learn = runtime.autocast_contexts(runtime.resolve_defaults(a3c.Args()).precision)
    assert not act._enabled and not learn._enabled
    monkeypatch.setattr(runtime.flags, "native_bf16", lambda: False)
    assert runtime.resolve_defaults(a3c.Args(envs_per_worker=k)).precision == "fp32"
    for explicit in ("fp32", "bf16", "bf16-learn"):
        assert runtime.resolve_defaults(a3c.Args(precision=explicit)).precision == explicit
    assert capsys.readouterr().err.count("warning") == 2  # the two bf16 ones, emulated here


def test_bf16_without_native_support_warns_in_one_line(monkeypatch, capsys):
    a3c = load_script("a3c_ff")
    monkeypatch.setattr(runtime.flags, "native_bf16", lambda: False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        runtime.resolve_defaults(a3c.Args(precision="fp32"))
        assert capsys.readouterr().err == ""  # fp32 never warns
        runtime.resolve_defaults(a3c.Args(precision="bf16"))
    err = capsys.readouterr().err
    assert err.startswith("warning: --precision bf16") and err.count("\n") == 1, err
    runtime.resolve_defaults(a3c.Args(precision="bf16-learn"))
    err = capsys.readouterr().err
    assert err.startswith("warning: --precision bf16-learn") and err.count("\n") == 1, err
    monkeypatch.setattr(runtime.flags, "native_bf16", lambda: True)
    runtime.resolve_defaults(a3c.Args(precision="bf16"))
    assert capsys.readouterr().err == ""


def test_native_bf16_reads_torchs_cpu_capabilities(monkeypatch):
    assert isinstance(runtime.native_bf16(), bool)
    monkeypatch.setattr(torch.cpu, "get_capabilities", lambda: {"avx512_bf16": False, "avx2": True})
    assert runtime.native_bf16() is False
    monkeypatch.setattr(torch.cpu, "get_capabilities", lambda: {"amx_bf16": True})
    assert runtime.native_bf16() is True


@pytest.mark.parametrize("name", ALL_SCRIPTS)
def test_help_shows_each_default_once(name, monkeypatch, capsys):
    """A flag whose default comes from others (None in Args) shows that default's text, once."""
    monkeypatch.setenv("COLUMNS", "100")
    code, _ = main_exit(load_script(name), ["--help"], monkeypatch, capsys, keep_out=True)
    out = capsys.readouterr().out
    assert code == 0
    # one entry per flag, its lines (tyro draws its box in ASCII when stdout is not a terminal)
    entries = re.split(r"\n│? +(?=--[a-z])", out)[1:]
    assert len(entries) > 30
    for entry in entries:
        assert entry.count("(default") <= 1, entry
    text = re.sub(r"[\s│]+", " ", out)  # tyro's box, its line breaks undone
    assert "(default: the number of CPU cores)" in text
    assert "(default: 1e6 for Catch, 1e8 for ALE ids)" in text


def test_help_into_a_closed_pipe_ends_quietly():
    """`python agents/a3c_ff.py --help | head -1`: the pipe is the process boundary."""
    import sys

    result = run_into_a_closed_pipe([sys.executable, str(SCRIPT_PATHS["a3c_ff"]), "--help"])
    assert result.stderr == "" and result.returncode == 1, result.stderr
