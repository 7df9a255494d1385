"""--track: a run logged to Weights & Biases, CleanRL's way (each TensorBoard scalar, against
global_step; the flags as its config), here in W&B's offline mode; without wandb, one line and
exit 2."""

import importlib.util

import pytest
from conftest import load_script, main_exit

TINY = ["--num-workers", "1", "--total-timesteps", "1500", "--eval-interval", "500",
        "--eval-episodes", "2", "--log-interval", "0.2"]  # fmt: skip


@pytest.mark.slow
def test_a_tracked_run_writes_its_flags_and_scalars_to_wandb(tmp_path, monkeypatch, capsys):
    pytest.importorskip("wandb")
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    run_dir = tmp_path / "run"
    argv = [*TINY, "--track", "--learning-rate", "0.000321", "--run-dir", str(run_dir)]
    code, err = main_exit(load_script("a3c_ff"), argv, monkeypatch, capsys)
    assert code == 0, err
    # What the command's exit does (W&B's atexit hook): W&B's service closes the run's record
    # file. finish() alone returned once, in a loaded slow tier, with the file still at its header.
    import wandb

    wandb.teardown()
    (record,) = run_dir.glob("wandb/offline-run-*/run-*.wandb")  # W&B's own log of the run
    data = record.read_bytes()
    for flag in (b"learning_rate", b"0.000321", b"wandb_project_name", b"deep-rl-video-games"):
        assert flag in data, flag  # the flags, as its config
    for scalar in (b"eval/mean_return", b"charts/SPS", b"losses/entropy", b"global_step"):
        assert scalar in data, scalar  # the TensorBoard scalars, and their x axis
    assert (run_dir / "evaluations.csv").exists()  # and the run's own files as ever


def test_track_without_wandb_is_one_line(tmp_path, monkeypatch, capsys):
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "wandb" else real(name, *a)
    )
    monkeypatch.chdir(tmp_path)
    code, err = main_exit(load_script("a3c_ff"), ["--track"], monkeypatch, capsys)
    assert code == 2 and err == "error: --track needs wandb: pip install -e './agents[wandb]'\n"
    assert list(tmp_path.iterdir()) == []


def test_without_track_nothing_of_wandb_is_made(tmp_path, monkeypatch):
    """Off by default: the run log starts no W&B run."""
    from a3c_runtime import run_log

    module = load_script("a3c_ff")
    args = module.Args()
    assert args.track is False
    started = []
    monkeypatch.setattr(run_log, "start_wandb", lambda *a: started.append(a))
    import a3c_runtime

    log = run_log.RunLog(tmp_path, a3c_runtime.resolve_defaults(args), 0.0)
    log.close()
    assert started == [] and not (tmp_path / "wandb").exists()
