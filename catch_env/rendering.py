"""A small pygame window for showing RGB frames, used by `render_mode="human"` and play."""

from __future__ import annotations

import numpy as np


class Window:
    """A pygame window that shows HxWx3 uint8 frames scaled up by an integer zoom.

    pygame is imported here, not at package import, so `catch_env` works without it.
    Works headless with `SDL_VIDEODRIVER=dummy`.
    """

    def __init__(self, title: str, frame_shape: tuple[int, int], zoom: int = 6) -> None:
        try:
            import pygame
        except ImportError as error:
            raise ImportError(
                'Human rendering needs pygame: pip install "catch-env[human]"'
            ) from error
        self.pygame = pygame
        # Only the modules we use: pygame.init() would also open the audio device.
        pygame.display.init()
        pygame.font.init()
        height, width = frame_shape
        self.size = (width * zoom, height * zoom)
        self.surface = pygame.display.set_mode(self.size)
        pygame.display.set_caption(title)
        self.clock = pygame.time.Clock()
        self.closed = False

    def show(self, frame: np.ndarray, fps: float | None = None, text: str | None = None) -> None:
        """Draw one frame (and an optional line of text at the top), then keep to `fps`."""
        pygame = self.pygame
        # Let the OS know the window is alive; closing it is handled by whoever polls events.
        pygame.event.pump()
        image = pygame.surfarray.make_surface(np.ascontiguousarray(frame.swapaxes(0, 1)))
        self.surface.blit(pygame.transform.scale(image, self.size), (0, 0))
        if text:
            font = pygame.font.Font(None, max(18, self.size[1] // 20))
            self.surface.blit(font.render(text, True, (255, 200, 0)), (6, 6))
        pygame.display.flip()
        if fps:
            self.clock.tick(fps)

    def close(self) -> None:
        if not self.closed:
            self.pygame.display.quit()
            self.closed = True
