"""Lazy imports of the optional packages and the once-per-process polyscope set-up."""

from __future__ import annotations

import os
from types import ModuleType

from ..errors import missing_extra

__all__ = ["backend", "ensure_init", "has_display", "pillow", "polyscope"]

#: Backend chosen when igljoin initialised polyscope (``None``: not by igljoin).
_STATE: dict[str, str | None] = {"backend": None}


def polyscope(feature: str = "igljoin.viz (inspection and pictures)") -> ModuleType:
    """Import polyscope, or raise :class:`~igljoin.errors.MissingExtraError` naming the extra."""
    try:
        import polyscope as ps
    except ImportError as exc:
        raise missing_extra("polyscope", "viz", feature) from exc
    return ps


def pillow(feature: str = "igljoin.viz pictures") -> ModuleType:
    """Import Pillow's ``PIL`` package (with Image, ImageDraw, ImageFont loaded)."""
    try:
        import PIL
        import PIL.Image
        import PIL.ImageDraw
        import PIL.ImageFont
    except ImportError as exc:
        raise missing_extra("pillow", "viz", feature) from exc
    return PIL


def has_display() -> bool:
    """Whether a window can be opened (an X11 or Wayland display is set)."""
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def ensure_init(*, headless: bool = False) -> ModuleType:
    """Initialise polyscope once per process and return the module.

    Parameters
    ----------
    headless : bool
        Prefer the off-screen EGL backend. Without a display EGL is used
        anyway. The first call decides: a polyscope backend cannot be
        re-initialised in one process, so later calls reuse it (also one
        initialised by the caller's own code).

    Returns
    -------
    module
        ``polyscope``.
    """
    ps = polyscope()
    if not ps.is_initialized():
        ps.set_use_prefs_file(False)  # else polyscope writes .polyscope.ini into the cwd
        ps.set_program_name("igljoin")
        name = "openGL3_egl" if headless or not has_display() else "auto"
        if name == "openGL3_egl":
            ps.set_allow_headless_backends(True)
            ps.set_verbosity(0)  # no EGL start-up chatter on stdout in scripts and the CLI
        ps.init(name)
        _STATE["backend"] = name
        ps.set_ground_plane_mode("none")
        # The very first frame of a process sets up state later frames inherit; draw it now,
        # so the first picture of a process equals every later one.
        ps.screenshot_to_buffer(transparent_bg=False)
    return ps


def backend() -> str | None:
    """The backend igljoin initialised polyscope with, or ``None``."""
    return _STATE["backend"]


def is_headless() -> bool:
    """Whether the running polyscope cannot show a window (EGL or mock backend)."""
    ps = polyscope()
    if _STATE["backend"] == "openGL3_egl":
        return True
    return bool(getattr(ps, "is_headless", lambda: False)())
