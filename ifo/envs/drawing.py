"""pygame, set up once for drawing off-screen from many threads (the maze's images, gymnasium's rgb_array frames).

Import this module before anything draws: it chooses the headless video driver, and it loads pygame's surfarray
now, in one thread. pygame loads surfarray lazily, and Python 3.11's lazy loading is not thread-safe: two sessions
drawing their first frame at once saw it half-loaded ("module 'pygame.surfarray' has no attribute 'pixels3d'").
"""

import os
import threading

os.environ.setdefault("SDL_VIDEODRIVER", "dummy")  # draw off-screen, never open a window
# No sound at all (SDL knows no driver of this name): gymnasium calls pygame.init(), which with a working driver,
# even "dummy", starts an audio thread that pygame.quit() must join; two sessions quitting at once deadlocked there.
# Without a driver SDL probes nothing either, so no ALSA errors in the logs.
os.environ.setdefault("SDL_AUDIODRIVER", "none")
os.environ.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
import pygame  # noqa: E402  (must come after the SDL setting)
from pygame.surfarray import pixels3d  # noqa: E402  (loads the module, see above)

__all__ = ["pygame", "pixels3d", "render_frame", "close_env"]

# gymnasium's CartPole, Acrobot and MountainCar draw with pygame.gfxdraw.filled_polygon, which lets go of the GIL
# and fills through one static buffer inside SDL_gfx: two sessions drawing at once smudged each other's frames.
_DRAW_LOCK = threading.Lock()


def render_frame(env):
    """`env.render()`, one environment at a time in this process (see _DRAW_LOCK)."""
    with _DRAW_LOCK:
        return env.render()


def close_env(env) -> None:
    """`env.close()` that leaves pygame running: gymnasium's close() of an environment that has drawn calls
    pygame.quit(), which would pull pygame away from every other session drawing in this process."""
    with _DRAW_LOCK:
        base = env.unwrapped
        if getattr(base, "screen", None) is not None:
            base.screen = None  # its surface goes with the environment; close() then has no pygame to quit
        env.close()
