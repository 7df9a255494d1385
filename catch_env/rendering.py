"""A small pygame window for showing RGB frames, used by `render_mode="human"` and play."""

from __future__ import annotations

import os
import sys
from typing import Any

import numpy as np

# SDL's video drivers without a screen: used only when SDL_VIDEODRIVER names one
HEADLESS_DRIVERS = ("dummy", "offscreen")
HEADLESS_HINT = "to play headless (tests, CI), set SDL_VIDEODRIVER=dummy"


class NoDisplayError(RuntimeError):
    """No display to open a window on, and no headless SDL driver asked for."""


def _import_pygame() -> Any:
    try:
        import pygame
    except ImportError as error:
        raise ImportError('Human rendering needs pygame: pip install "catch-env[human]"') from error
    return pygame


def _headless_requested() -> bool:
    requested = os.environ.get("SDL_VIDEODRIVER", "").lower().split(",")
    return any(driver.strip() in HEADLESS_DRIVERS for driver in requested)


def _init_display(pygame: Any) -> None:
    """pygame's display, on a screen: NoDisplayError where there is none (SDL would fall back
    to its offscreen driver and play invisibly, or fail with a raw pygame.error), unless
    SDL_VIDEODRIVER asks for a headless driver."""
    if (
        not os.environ.get("SDL_VIDEODRIVER")
        and sys.platform.startswith("linux")
        and not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    ):
        raise NoDisplayError(f"no display: DISPLAY and WAYLAND_DISPLAY are unset; {HEADLESS_HINT}")
    try:
        pygame.display.init()
    except pygame.error as error:
        raise NoDisplayError(
            f"no display: SDL cannot open one ({error}); {HEADLESS_HINT}"
        ) from None
    driver = pygame.display.get_driver()
    if driver in HEADLESS_DRIVERS and not _headless_requested():
        pygame.display.quit()
        raise NoDisplayError(f"no display: SDL found only its {driver} driver; {HEADLESS_HINT}")


def check_display() -> None:
    """Raise NoDisplayError (or ImportError without pygame) if no window can open here; leaves
    pygame's display as it found it."""
    pygame = _import_pygame()
    if pygame.display.get_init():
        return
    _init_display(pygame)
    pygame.display.quit()


class Window:
    """A pygame window that shows HxWx3 uint8 frames scaled up by an integer zoom, with an
    optional status bar below the frame (so that text never covers the game).

    pygame is imported here, not at package import, so `catch_env` works without it.
    Without a display it raises NoDisplayError; it works headless only when asked to, with
    `SDL_VIDEODRIVER=dummy`.
    """

    def __init__(
        self, title: str, frame_shape: tuple[int, int], zoom: int = 6, status_bar: bool = False
    ) -> None:
        pygame = _import_pygame()
        self.pygame = pygame
        # Only the modules we use: pygame.init() would also open the audio device.
        _init_display(pygame)
        pygame.font.init()
        height, width = frame_shape
        self.size = (width * zoom, height * zoom)
        self.font = pygame.font.Font(None, max(18, self.size[1] // 20))
        self.bar_height = self.font.get_linesize() + 8 if status_bar else 0
        try:
            self.surface = pygame.display.set_mode((self.size[0], self.size[1] + self.bar_height))
        except pygame.error as error:
            pygame.display.quit()
            raise NoDisplayError(f"no display: SDL cannot open a window ({error})") from None
        pygame.display.set_caption(title)
        self.clock = pygame.time.Clock()
        self.closed = False

    def show(self, frame: np.ndarray, fps: float | None = None, text: str | None = None) -> None:
        """Draw one frame (and an optional line of text: in the status bar, if the window has
        one, else over the frame's top), then keep to `fps`."""
        pygame = self.pygame
        # Let the OS know the window is alive; closing it is handled by whoever polls events.
        pygame.event.pump()
        image = pygame.surfarray.make_surface(np.ascontiguousarray(frame.swapaxes(0, 1)))
        self.surface.blit(pygame.transform.scale(image, self.size), (0, 0))
        if self.bar_height:
            self.surface.fill((0, 0, 0), (0, self.size[1], self.size[0], self.bar_height))
        if text:
            top = self.size[1] + 4 if self.bar_height else 6
            self.surface.blit(self.font.render(text, True, (255, 200, 0)), (6, top))
        pygame.display.flip()
        if fps:
            self.clock.tick(fps)

    def close(self) -> None:
        if not self.closed:
            self.pygame.display.quit()
            self.closed = True
