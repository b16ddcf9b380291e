"""Which OpenGL backend MuJoCo renders with (``MUJOCO_GL``), chosen before mujoco is imported.

A light module (the standard library alone): the console command asks it before any heavy
import, since mujoco reads ``MUJOCO_GL`` once, when it is first imported.
"""

from __future__ import annotations

import os
import sys

OFF = ("disable", "disabled", "off", "false", "0")


def default_gl() -> str:
    """The backend to render with where the user chose none: EGL on a Linux machine without a
    display (offscreen: Mesa's software rasterizer on a CPU, the driver's EGL on a GPU), else
    "" (MuJoCo's own choice: GLFW with a display, CGL on macOS)."""
    headless = not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))
    return "egl" if sys.platform.startswith("linux") and headless else ""


def choose_for_rendering() -> str | None:
    """Sets ``MUJOCO_GL`` for rendering unless the user set it or mujoco is already imported;
    returns why rendering cannot work in this process (None when it can be tried)."""
    if "mujoco" not in sys.modules:
        if default_gl():
            os.environ.setdefault("MUJOCO_GL", default_gl())
        chosen = os.environ.get("MUJOCO_GL", "").lower()
    else:  # what mujoco read at its import (the variable may have changed since)
        context = sys.modules.get("mujoco.rendering.classic.gl_context")
        chosen = str(getattr(context, "_MUJOCO_GL", os.environ.get("MUJOCO_GL", ""))).lower()
    if chosen in OFF or (not chosen and default_gl()):
        return (f"mujoco was imported with MUJOCO_GL={chosen or 'unset'}, which cannot render "
                "offscreen here: set MUJOCO_GL=egl before importing mujoco or minatt_jax (the "
                "render command does)")  # fmt: skip
    return None
