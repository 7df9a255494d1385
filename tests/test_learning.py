"""The agents learn: each distinct worker loop (FF's, which LWS, SS, WW and LPQ run; the LSTM's;
GLPQ's) reaches a fixed score on Catch-v0 within a fixed budget. A change that keeps every shape,
hand-computed value and drift test intact but stops learning fails here.

One worker, so that a run is exactly repeatable on a machine (no Hogwild race; the evaluator
plays its own seeded episodes); the fast setting's batched actors (K = 16 envs, t_max = 5) and
100,000 steps, over which the learning rate anneals to 0, then 500 evaluation episodes. Each
threshold sits well below what the loop's runs reach and well above random play (0.2, give or take
0.02 over 500 episodes): seeds 2 and 3 ended at the scores beside it, and a machine whose floating
point takes seed 1's run another way is one more such draw, not a run at the threshold. The three
run side by side, each main() in a forked copy of the test process (no new interpreter), so that
one-worker runs fill the two cores.
"""

import os
import sys

import pytest
from conftest import load_script, read_evaluations

STEPS, EPISODES = 100_000, 500
# loop: (the script's own flags, the threshold); the scores its runs of seeds 2 and 3 reached
# (500 episodes; seed 1, the test's, is exactly repeatable and passes), random play about 0.2
LEARNERS = {
    "a3c_ff": ([], 0.35),  # 0.558, 0.452
    "a3c_lstm": ([], 0.30),  # 0.428, 0.364
    # GLPQ with the thesis code's mu (as run): eq. 7.7's learns too slowly for this budget
    "a3c_glpq": (["--mu-form", "code"], 0.30),  # 0.468, 0.380
}
RANDOM_PLAY = 0.28  # above what an untrained network scores on 500 episodes (0.19-0.23)


def start_run(name: str, argv: list[str]) -> int:
    """main() of the script in a forked copy of this process, as `python agents/<name>.py *argv`
    would run it; the child's pid (its exit status is main()'s exit code)."""
    module = load_script(name)  # imported before the fork, once
    pid = os.fork()
    if pid:
        return pid
    code = 1
    try:
        sys.argv = [f"{name}.py", *argv]
        code = module.main() or 0
    except SystemExit as e:
        code = e.code if isinstance(e.code, int) else 1
    finally:
        os._exit(code)


@pytest.mark.slow
def test_each_worker_loop_learns_catch(tmp_path):
    """The three runs side by side (each is one worker: together they take the two cores)."""
    pids = {}
    for name, (flags, _) in LEARNERS.items():
        argv = [
            *flags,
            *("--num-workers", "1", "--envs-per-worker", "16", "--t-max", "5", "--seed", "1"),
            *("--total-timesteps", str(STEPS), "--eval-interval", str(STEPS)),
            *("--eval-episodes", str(EPISODES), "--run-dir", str(tmp_path / name)),
        ]
        pids[name] = start_run(name, argv)
    codes = {name: os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1]) for name, pid in pids.items()}
    assert codes == dict.fromkeys(LEARNERS, 0), codes
    scores = {}
    for name, (_, threshold) in LEARNERS.items():
        start, final = [float(row["mean_return"]) for row in read_evaluations(tmp_path / name)]
        assert start < RANDOM_PLAY, f"{name}'s untrained network already scores {start}"
        scores[name] = (final, threshold)
    print(f"(final score, threshold) after {STEPS:,} steps: {scores}")
    assert all(final >= threshold for final, threshold in scores.values()), (
        f"(final score, threshold) after {STEPS:,} steps: {scores}"
    )
