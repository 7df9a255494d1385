"""Human play (catch_env.play), driven headless with posted key events, and the examples."""

from __future__ import annotations

import os

# Headless SDL, set before pygame opens a display: no window, no sound device.
os.environ["SDL_VIDEODRIVER"] = "dummy"
os.environ["SDL_AUDIODRIVER"] = "dummy"
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")

import functools  # noqa: E402
import re  # noqa: E402
import select  # noqa: E402
import signal  # noqa: E402
import subprocess  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402
import pygame  # noqa: E402
import pytest  # noqa: E402

import catch_env  # noqa: E402, F401  (registers Catch-v0)
from catch_env import play as play_module  # noqa: E402
from catch_env.play import build_key_map, main, play  # noqa: E402
from catch_env.rendering import Window  # noqa: E402

EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
# Far above any real frame rate, so Window.show never waits.
FAST = 100_000
ATARI_MEANINGS = [
    "NOOP", "FIRE", "UP", "RIGHT", "LEFT", "DOWN", "UPRIGHT", "UPLEFT", "DOWNRIGHT",
    "DOWNLEFT", "UPFIRE", "RIGHTFIRE", "LEFTFIRE", "DOWNFIRE", "UPRIGHTFIRE", "UPLEFTFIRE",
    "DOWNRIGHTFIRE", "DOWNLEFTFIRE",
]  # fmt: skip


def post_key(key: int, down: bool = True) -> None:
    """Queue a key press or release, as the keyboard would."""
    event_type = pygame.KEYDOWN if down else pygame.KEYUP
    pygame.event.post(pygame.event.Event(event_type, key=key, mod=0, unicode="", scancode=0))


def post_before_play(*events: pygame.event.Event) -> None:
    """Queue events before play() opens its window (the queue needs the display up)."""
    pygame.display.init()
    pygame.event.clear()
    for event in events:
        pygame.event.post(event)


def key_down(key: int) -> pygame.event.Event:
    return pygame.event.Event(pygame.KEYDOWN, key=key, mod=0, unicode="", scancode=0)


def start_paddle(seed: int) -> int:
    env = gym.make("Catch-v0")
    env.reset(seed=seed)
    return env.unwrapped.paddle


# A seed whose paddle starts far enough from both walls for three moves of 2 cells.
MID_SEED = next(seed for seed in range(100) if 8 <= start_paddle(seed) <= 15)


@pytest.fixture(autouse=True)
def _no_display_left_open():
    pygame.display.quit()  # in case another test file left one open
    yield
    # Each play() closes its window; a display left open would leak events into the next.
    assert not pygame.display.get_init()


@pytest.mark.parametrize(
    ("key", "direction"),
    [(pygame.K_LEFT, -1), (pygame.K_a, -1), (pygame.K_RIGHT, 1), (pygame.K_d, 1)],
)
def test_held_key_moves_the_paddle_until_released(key: int, direction: int) -> None:
    paddles, actions = [], []

    def on_step(env: gym.Env, action: int, reward: float) -> None:
        paddles.append(env.unwrapped.paddle)
        actions.append(action)
        if len(paddles) == 2:
            post_key(key, down=False)

    post_before_play(key_down(key))
    stats = play(fps=FAST, seed=MID_SEED, max_steps=3, on_step=on_step)

    start = start_paddle(MID_SEED)
    # Two steps with the key held (2 cells each), then the release makes it NOOP.
    assert paddles == [start + 2 * direction, start + 4 * direction, start + 4 * direction]
    assert actions == [1 if direction < 0 else 2] * 2 + [0]
    assert stats.steps == 3
    assert stats.quit_reason == "max_steps"


def test_key_tapped_between_frames_still_acts_once() -> None:
    actions = []
    post_before_play(key_down(pygame.K_RIGHT))
    pygame.event.post(pygame.event.Event(pygame.KEYUP, key=pygame.K_RIGHT, mod=0))
    play(fps=FAST, seed=MID_SEED, max_steps=2, on_step=lambda env, a, r: actions.append(a))
    assert actions == [2, 0]


def test_episodes_are_scored_and_shown(monkeypatch: pytest.MonkeyPatch) -> None:
    """A key-pressing bot that follows the ball scores; idle play scores less."""
    shown_texts = []
    original_show = Window.show

    def recording_show(self, frame, fps=None, text=None):
        shown_texts.append(text)
        original_show(self, frame, fps=fps, text=text)

    monkeypatch.setattr(Window, "show", recording_show)

    def follow_ball(env: gym.Env, action: int, reward: float) -> None:
        game = env.unwrapped
        target = game.ball_col + game.ball_vx
        post_key(pygame.K_LEFT, down=target < game.paddle)
        post_key(pygame.K_RIGHT, down=target > game.paddle)

    pygame.display.init()
    pygame.event.clear()
    # max_steps only stops a broken play() from running forever.
    bot = play(fps=FAST, seed=3, max_episodes=4, max_steps=200, on_step=follow_ball)
    bot_texts = list(shown_texts)
    pygame.display.init()
    pygame.event.clear()
    idle = play(fps=FAST, seed=3, max_episodes=4, max_steps=200)

    for stats in (bot, idle):
        # Catch episodes last 15 steps and pay 0 or 1.
        assert stats.episodes == 4 and stats.steps == 60
        assert set(stats.scores) <= {0.0, 1.0}
        assert stats.quit_reason == "max_episodes"
    assert sum(bot.scores) == 4 > sum(idle.scores)
    assert bot_texts[0] == "episode 1   score 0   total 0"
    assert "episode 2   score 0   total 1" in bot_texts
    # The last frame shown: episode 4 just finished, caught, 4 caught in all.
    assert bot_texts[-1] == "episode 4   score 1   total 4"


def test_escape_quits_before_any_step() -> None:
    post_before_play(key_down(pygame.K_ESCAPE))
    # max_steps only stops a broken play() from running forever.
    stats = play(fps=FAST, seed=0, max_steps=50)
    assert stats.quit_reason == "escape"
    assert stats.steps == 0 and stats.episodes == 0


def test_escape_mid_game_quits_after_that_step() -> None:
    def press_escape_at_step_5(env: gym.Env, action: int, reward: float) -> None:
        if env.unwrapped.ball_row == 4 + 5:
            post_key(pygame.K_ESCAPE)

    pygame.display.init()
    pygame.event.clear()
    stats = play(fps=FAST, seed=0, max_steps=50, on_step=press_escape_at_step_5)
    assert stats.quit_reason == "escape"
    assert stats.steps == 5


def test_closing_the_window_quits() -> None:
    post_before_play(pygame.event.Event(pygame.QUIT))
    stats = play(fps=FAST, seed=0, max_steps=50)
    assert stats.quit_reason == "window closed"
    assert stats.steps == 0


@pytest.mark.parametrize("event_type", ["APP_LOWMEMORY", "SYSWMEVENT", "CLIPBOARDUPDATE"])
def test_events_other_than_quit_and_keys_are_ignored(event_type: str) -> None:
    """The system's events (numbered below and above the key events) neither quit nor press."""
    post_before_play(pygame.event.Event(getattr(pygame, event_type)))
    stats = play(fps=FAST, seed=0, max_steps=3)
    assert (stats.quit_reason, stats.steps) == ("max_steps", 3)


def test_sigterm_mid_game_stops_after_that_step() -> None:
    def refuse(signum: int, frame: object) -> None:
        # Stands in for the default action (killing pytest) should play() not catch it.
        raise AssertionError("play() let SIGTERM through")

    def sigterm_at_step_3(env: gym.Env, action: int, reward: float) -> None:
        if env.unwrapped.ball_row == 4 + 3:
            os.kill(os.getpid(), signal.SIGTERM)

    previous = signal.signal(signal.SIGTERM, refuse)
    try:
        pygame.display.init()
        pygame.event.clear()
        stats = play(fps=FAST, seed=0, max_steps=50, on_step=sigterm_at_step_3)
        assert signal.getsignal(signal.SIGTERM) is refuse  # put back after play()
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert stats.quit_reason == "stopped by SIGTERM"
    assert stats.steps == 3


def wait_for_stop_handlers(pid: int, timeout: float = 60) -> None:
    """Wait until process `pid` catches SIGTERM: record_stop_signals sets SIGINT's handler, then
    SIGTERM's (Python catches SIGINT from its start, so only SIGTERM tells). Linux shows the
    caught signals in /proc/<pid>/status; elsewhere, wait a second."""
    status = Path(f"/proc/{pid}/status")
    if not status.exists():
        time.sleep(1)
        return
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        caught = re.search(r"^SigCgt:\s*([0-9a-f]+)$", status.read_text(), re.MULTILINE)
        if caught and int(caught[1], 16) >> (signal.SIGTERM - 1) & 1:
            return
        time.sleep(0.01)
    raise AssertionError(f"catch-play did not catch SIGTERM within {timeout} s")


@pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals")
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT])
def test_catch_play_stopped_by_a_signal_says_so_and_exits_0(signum: signal.Signals) -> None:
    """The command, headless in a subprocess: a signal ends it with its summary, as Ctrl-C
    always did, and SIGTERM is no longer reported as "window closed" (SDL's reading)."""
    process = subprocess.Popen(
        [sys.executable, "-m", "catch_env.play", "--seed", "0"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # A shell without job control starts background jobs with SIGINT ignored, and
        # catch-play rightly keeps it ignored: give the child the default, as a terminal does.
        preexec_fn=functools.partial(signal.signal, signal.SIGINT, signal.SIG_DFL),
    )
    try:
        ready, _, _ = select.select([process.stdout], [], [], 60)
        assert ready, "catch-play printed nothing in 60 s"
        assert "Esc or closing the window quits" in process.stdout.readline()
        # The controls line comes just before play() takes over the signals: wait for them.
        wait_for_stop_handlers(process.pid)
        process.send_signal(signum)
        out, err = process.communicate(timeout=30)
    finally:
        process.kill()
        process.wait()
    assert process.returncode == 0, err
    assert f"(quit: stopped by {signum.name})" in out
    assert "Traceback" not in err


def test_atari_game_plays_with_its_own_key_map() -> None:
    pytest.importorskip("ale_py")
    actions = []
    post_before_play(key_down(pygame.K_SPACE), key_down(pygame.K_LEFT))
    stats = play(
        "BreakoutNoFrameskip-v4",
        fps=FAST,
        seed=0,
        max_steps=5,
        on_step=lambda env, action, reward: actions.append(action),
    )
    # Breakout has NOOP FIRE RIGHT LEFT and no LEFTFIRE: space + left is LEFT.
    assert actions == [3] * 5
    assert stats.steps == 5


def test_key_map_matches_combinations_and_falls_back() -> None:
    atari = build_key_map(ATARI_MEANINGS)
    assert atari[frozenset()] == ATARI_MEANINGS.index("NOOP")
    assert atari[frozenset({"UP", "RIGHT"})] == ATARI_MEANINGS.index("UPRIGHT")
    assert atari[frozenset({"DOWN", "LEFT", "FIRE"})] == ATARI_MEANINGS.index("DOWNLEFTFIRE")
    # Opposite directions cancel.
    assert atari[frozenset({"LEFT", "RIGHT", "FIRE"})] == ATARI_MEANINGS.index("FIRE")
    catch = build_key_map(["NOOP", "LEFT", "RIGHT"])
    assert catch[frozenset({"LEFT"})] == 1 and catch[frozenset({"RIGHT"})] == 2
    # Buttons Catch lacks are ignored rather than blocking the move.
    assert catch[frozenset({"UP", "LEFT", "FIRE"})] == 1
    assert catch[frozenset({"FIRE"})] == 0
    assert len(catch) == 2**5


def test_main_plays_and_prints_a_summary(
    capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    # A step limit main() lacks, so a broken episode count fails instead of hanging.
    monkeypatch.setattr(play_module, "play", functools.partial(play, max_steps=100))
    main(["--fps", str(FAST), "--seed", "0", "--episodes", "2", "--zoom", "2"])
    out = capsys.readouterr().out
    assert "Catch-v0: 2 episode(s)" in out and "30 steps" in out


@pytest.mark.parametrize(
    ("environment", "reason"),
    [
        ({}, "DISPLAY and WAYLAND_DISPLAY are unset"),  # SDL would play in its offscreen driver
        ({"SDL_VIDEODRIVER": "x11"}, "SDL cannot open one (x11 not available)"),
        ({"DISPLAY": ":4242"}, ""),  # no server there: SDL fails, or falls back to offscreen
    ],
)
def test_catch_play_without_a_display_exits_2_in_one_line(
    environment: dict[str, str],
    reason: str,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    for name in ("SDL_VIDEODRIVER", "DISPLAY", "WAYLAND_DISPLAY"):  # the tests' dummy driver too
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("XDG_RUNTIME_DIR", str(tmp_path))  # no Wayland socket to find
    for name, value in environment.items():
        monkeypatch.setenv(name, value)
    with pytest.raises(SystemExit) as exit_info:
        main(["--episodes", "1"])
    assert exit_info.value.code == 2
    out, err = capsys.readouterr()
    assert out == ""  # not even the controls line: nothing is played
    assert err.startswith("catch-play: error: no display: ") and err.count("\n") == 1, err
    assert reason in err and "set SDL_VIDEODRIVER=dummy" in err


def test_the_status_line_is_drawn_below_the_game_not_over_it() -> None:
    """Over the frame, the status line hid Breakout's score."""
    window = Window("status", (10, 20), zoom=3, status_bar=True)
    try:
        window.show(np.full((10, 20, 3), 40, dtype=np.uint8), text="episode 1   score 0")
        pixels = pygame.surfarray.array3d(window.surface).swapaxes(0, 1)  # (height, width, 3)
    finally:
        window.close()
    assert pixels.shape[:2] == (30 + window.bar_height, 60) and window.bar_height > 0
    assert (pixels[:30] == 40).all()  # the game's frame, untouched
    assert (pixels[30:] != 0).any()  # the text, in the bar


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--env", "NoSuchGame-v0"], "catch-play --list-envs"),
        (["--env", "CartPole-v1"], "no named discrete actions"),
        (["--fps", "-5"], "argument --fps: must be positive"),
        (["--zoom", "1.5"], "argument --zoom: expected an integer"),
        (["--episodes", "0"], "argument --episodes: must be positive"),
    ],
)
def test_bad_flags_exit_with_a_clear_message(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


def test_unknown_env_id_in_play_raises_value_error() -> None:
    with pytest.raises(ValueError, match="NoSuchGame-v0.*--list-envs"):
        play("NoSuchGame-v0")


def test_list_envs_names_catch_and_atari(capsys: pytest.CaptureFixture[str]) -> None:
    main(["--list-envs"])
    ids = capsys.readouterr().out.split()
    assert "Catch-v0" in ids
    if play_module.importlib.util.find_spec("ale_py"):
        assert "BreakoutNoFrameskip-v4" in ids


def run_example(*args: str) -> str:
    result = subprocess.run(
        [sys.executable, *args], capture_output=True, text=True, timeout=60, check=True
    )
    return result.stdout


def test_random_agent_example_catches_about_one_in_five() -> None:
    out = run_example(str(EXAMPLES / "random_agent.py"), "--episodes", "400", "--seed", "1")
    caught, episodes, rate = re.search(
        r"(\d+)/(\d+) balls caught: catch rate ([\d.]+)", out
    ).groups()
    assert int(episodes) == 400
    assert float(rate) == pytest.approx(int(caught) / 400, abs=1e-3)
    assert 0.12 < float(rate) < 0.3


@pytest.mark.skipif(not play_module.importlib.util.find_spec("ale_py"), reason="needs ale-py")
def test_random_agent_example_reports_an_atari_games_raw_score() -> None:
    out = run_example(str(EXAMPLES / "random_agent.py"), "--env", "PongNoFrameskip-v4", "-n", "1")
    score = float(re.search(r"PongNoFrameskip-v4: mean score (-?[\d.]+) \+- 0.00 over 1 ", out)[1])
    assert -21 <= score <= -15  # a random paddle rarely scores against Pong's CPU player


def test_vector_env_example_counts_episodes_with_next_step_autoreset() -> None:
    out = run_example(str(EXAMPLES / "vector_env.py"), "--num-envs", "8", "--steps", "100")
    # Each game ends at steps 15, 31, ..., 95 (15 played steps, then 1 reset step):
    # 6 episodes and 6 reset steps per env.
    assert "8 envs x 100 steps: 48 episodes" in out
    assert f"{8 * 100 - 48} game steps" in out
    catches, rate = re.search(r"(\d+) catches \(catch rate ([\d.]+)\)", out).groups()
    assert 0 <= int(catches) <= 48 and float(rate) == pytest.approx(int(catches) / 48, abs=1e-3)
    assert re.search(r"[\d,]+ env steps/s", out)


@pytest.mark.parametrize("limit", ["max_episodes", "max_steps"])
@pytest.mark.parametrize("value", [0, -1])
def test_play_refuses_a_limit_below_one(limit: str, value: int) -> None:
    with pytest.raises(ValueError, match=f"{limit} must be positive, got {value}"):
        play("Catch-v0", **{limit: value})


@pytest.mark.parametrize(
    ("env_id", "kwargs", "fps"),
    [
        ("BreakoutNoFrameskip-v4", {}, 60.0),  # one frame a step
        ("ALE/Breakout-v5", {}, 15.0),  # 4 frames a step
        ("ALE/Breakout-v5", {"frameskip": (2, 5)}, 20.0),  # 2, 3 or 4 frames: 3 on average
        ("Catch-v0", {}, None),  # its render_fps
    ],
)
def test_default_fps_is_the_games_real_speed(env_id: str, kwargs: dict, fps: float | None) -> None:
    pytest.importorskip("ale_py")
    env = gym.make(env_id, **kwargs)
    try:
        expected = env.metadata["render_fps"] if fps is None else fps
        assert play_module.default_fps(env) == pytest.approx(expected)
    finally:
        env.close()


@pytest.mark.parametrize("limit", ["max_episodes", "max_steps"])
def test_a_limit_ends_the_session_on_its_step(limit: str) -> None:
    """The step that reaches the limit ends the session there: a key pressed just after it
    (Esc, queued by the step's callback) is not read, so the quit reason stays the limit's."""
    steps: list[bool] = []  # whether each step ended its episode

    def press_escape_at_the_limit(env, action, reward) -> None:
        steps.append(env.unwrapped.ball_row == env.unwrapped.rules.paddle_row)
        if (sum(steps) if limit == "max_episodes" else len(steps)) == 1 and (
            limit == "max_steps" or steps[-1]
        ):
            post_key(pygame.K_ESCAPE)

    stats = play(fps=FAST, seed=3, on_step=press_escape_at_the_limit, **{limit: 1})
    assert stats.quit_reason == limit
    assert stats.steps == len(steps)  # no step after the limit's
    assert (stats.episodes, stats.steps > 1) == (
        (1, True) if limit == "max_episodes" else (0, False)
    )
