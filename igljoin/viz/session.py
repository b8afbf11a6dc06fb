"""Interactive inspection: :class:`Session` and :func:`inspect`.

Every change the panel makes goes through a plain method of
:class:`Session` (:meth:`~Session.set_weight`, :meth:`~Session.set_smooth`,
:meth:`~Session.set_iterations`, :meth:`~Session.resolve`, ...); the ImGui
callback :meth:`~Session.frame` only draws widgets and calls them, so the
same methods can be driven from scripts and tests (with ``ps.frame_tick()``
in place of ``ps.show()``).
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from typing import Any

from ..atomic import atomic_path, atomic_write_text
from ..boundary import Curve
from ..errors import IgljoinError, OptionsError, WeldError
from ..io import write_mesh
from ..join import JoinResult, JoinSolver
from ..options import JoinOptions
from . import colors
from ._backend import ensure_init, is_headless, pillow
from .camera import VIEWS, frame_camera
from .headless import default_title, render
from .scene import Scene

__all__ = ["ITERATION_RANGE", "WEIGHTS", "WEIGHT_RANGES", "Session", "inspect"]

#: Panel weight names and the options they set.
WEIGHTS = {"shape": "shape_weight", "stretch": "stretch_weight", "smooth": "smooth_weight"}
#: Slider ranges (logarithmic sliders; a script may set any value the options accept).
WEIGHT_RANGES = {"shape": (0.01, 100.0), "stretch": (0.01, 100.0), "smooth": (0.01, 1000.0)}
ITERATION_RANGE = (1, 2000)
#: RGBA of the panel's warnings line when the result has quality warnings (the
#: orange of the pictures' notice, :data:`igljoin.viz.overlay.WARNING_COLOR`).
WARNING_RGBA = (1.0, 170 / 255, 60 / 255, 1.0)

#: The session :func:`inspect` opened last (a new one closes it).
_ACTIVE: list = []


def _solver_from_result(result: JoinResult) -> JoinSolver:
    """A solver that reproduces ``result``: its rest guest (seam points already inserted)."""
    seams = getattr(result, "seams", None)
    if seams and len(seams) > 1:
        pairs = [
            (
                Curve(indices=sm.host_curve, closed=sm.closed),
                Curve(indices=sm.seam, closed=sm.closed),
            )
            for sm in seams
        ]
        return JoinSolver(result.host, result.rest_guest, seams=pairs, options=result.options)
    return JoinSolver(
        result.host,
        result.rest_guest,
        Curve(indices=result.host_curve, closed=result.closed),
        Curve(indices=result.seam, closed=result.closed),
        result.options,
    )


class Session:
    """State of an interactive inspection; the panel calls its methods.

    Parameters
    ----------
    source : JoinSolver or JoinResult
        A solver is solved once and re-solved live. A result is shown as is;
        the first re-solve builds a solver from it (its rest guest and seam).
    title : str, optional
        Case name shown in the panel and in saved pictures.
    limit : float
        Area ratio at full colour.
    live : bool
        Re-solve as soon as a setting changes (a slider: when released).
    output_dir : str or os.PathLike
        Where the save buttons write.

    Attributes
    ----------
    result : JoinResult
        The result on display.
    solver : JoinSolver or None
    pending : dict
        Option changes not yet solved.
    message : str
        Last status or error shown in the panel.
    frames : int
        Panel frames drawn so far.
    """

    def __init__(
        self,
        source: Any,
        *,
        title: str | None = None,
        limit: float = colors.AREA_RATIO_LIMIT,
        live: bool = True,
        output_dir: str | os.PathLike = ".",
    ):
        if isinstance(source, JoinSolver):
            self.solver: JoinSolver | None = source
            t0 = time.perf_counter()
            self.result = source.solve()
            self.solve_seconds = time.perf_counter() - t0
        elif isinstance(source, JoinResult):
            self.solver = None
            self.result = source
            self.solve_seconds = float(source.timings.get("total", 0.0))
        else:
            raise OptionsError(
                f"inspect needs an igljoin.JoinSolver or JoinResult, got {type(source).__name__}"
            )
        self.ps = ensure_init()
        self.ps.set_background_color(colors.polyscope_background(colors.BACKGROUND))
        self.title = title if title is not None else default_title(self.result)
        self.limit = float(limit)
        self.live = bool(live)
        self.output_dir = Path(output_dir)
        self.pending: dict[str, Any] = {}
        self.message = ""
        self.frames = 0
        self.refactored = False
        self.scene: Scene | None = Scene(self.ps, self.result, solver=self.solver, limit=self.limit)

    # -- settings ---------------------------------------------------------------------------

    @property
    def options(self) -> JoinOptions:
        """The options the next solve will use (current options plus pending changes)."""
        base = self.solver.options if self.solver is not None else self.result.options
        return base.replace(**self.pending) if self.pending else base

    def _change(self, resolve: bool | None, **changes: Any) -> JoinResult | None:
        base = self.solver.options if self.solver is not None else self.result.options
        base.replace(**{**self.pending, **changes})  # validates: OptionsError names the option
        self.pending.update(changes)
        if resolve or (resolve is None and self.live):
            return self.resolve()
        return None

    def set_weight(self, name: str, value: float, *, resolve: bool | None = None):
        """Set the ``"shape"``, ``"stretch"`` or ``"smooth"`` weight (the sliders call this).

        Parameters
        ----------
        name : {"shape", "stretch", "smooth"}
        value : float
        resolve : bool, optional
            Re-solve now; default: when the session is live.

        Returns
        -------
        JoinResult or None
            The new result if it re-solved.
        """
        if name not in WEIGHTS:
            raise OptionsError(f"weight {name!r} is not one of {', '.join(map(repr, WEIGHTS))}")
        return self._change(resolve, **{WEIGHTS[name]: float(value)})

    def set_iterations(self, n: int, *, resolve: bool | None = None):
        """Set the maximum number of iterations (reuses the factorization)."""
        return self._change(resolve, max_iterations=int(n))

    def set_smooth(self, flag: bool, *, resolve: bool | None = None):
        """Switch the smooth-join term on or off (refactors)."""
        return self._change(resolve, smooth=bool(flag))

    def toggle_smooth(self, *, resolve: bool | None = None):
        """Switch the smooth-join term over."""
        return self.set_smooth(not self.options.smooth, resolve=resolve)

    def resolve(self) -> JoinResult:
        """Solve with the pending changes and show the new result.

        The solver keeps its factorization when only the iteration settings
        changed and refactors when a weight or the smooth term changed
        (:attr:`refactored` says which happened).
        """
        scene = self._open_scene()
        if self.solver is None:
            self.solver = _solver_from_result(self.result)
        before = self.solver.factorizations
        t0 = time.perf_counter()
        result = self.solver.solve(**self.pending)
        self.solve_seconds = time.perf_counter() - t0
        self.pending.clear()
        self.refactored = self.solver.factorizations != before
        self.result = result
        scene.update(result, self.solver)
        self.message = f"re-solved in {1000 * self.solve_seconds:.0f} ms" + (
            " (refactored)" if self.refactored else " (factorization reused)"
        )
        return result

    # -- display ----------------------------------------------------------------------------

    def _open_scene(self) -> Scene:
        if self.scene is None:
            raise RuntimeError("this session is closed; open a new one with igljoin.viz.inspect")
        return self.scene

    def set_quantity(self, name: str) -> None:
        """Colour the guest by a quantity (see :attr:`Scene.available_quantities`)."""
        self._open_scene().set_quantity(name)

    def show_rest(self, flag: bool) -> None:
        """Show or hide the original guest."""
        self._open_scene().set_rest(flag)

    def show_tangents(self, flag: bool) -> None:
        """Show or hide the host's and the guest's cross-seam tangents."""
        self._open_scene().set_tangents(flag)

    def show_merged(self, flag: bool) -> bool:
        """Show the welded mesh instead of host and guest, when the result has one."""
        shown = self._open_scene().set_merged(flag)
        if flag and not shown:
            self.message = self.scene.merged_error or "no welded mesh"
        return shown

    def look(self, view: str = "side") -> None:
        """Point the camera at the seam: ``"side"`` (across it) or ``"along"`` it."""
        if view not in VIEWS:
            raise OptionsError(f"view={view!r} must be 'side' or 'along'")
        w, h = self.ps.get_window_size()
        cam = frame_camera(self.result, view, w / max(h, 1))
        self.ps.set_vertical_fov_degrees(cam.fov_deg)
        self.ps.look_at_dir(cam.position, cam.target, cam.up)

    def figures(self) -> list[str]:
        """The report's key figures, one line each, as the panel shows them."""
        m = self.result.metrics
        gap, crease = m.get("seam_gap", {}), m.get("crease_deg", {})
        ratio, change = m.get("area_ratio", {}), m.get("area_change", {})
        total = float(self.result.report()["timings"].get("total", 0.0))
        lines = [
            f"seam gap: max {gap.get('max', float('nan')):.2e} "
            f"({gap.get('relative_max', float('nan')):.1e} seam edges)",
            f"crease: mean {crease.get('mean') or 0:.2f} deg, max {crease.get('max') or 0:.2f} deg",
            f"area ratio: min {ratio.get('min') or 0:.3f}, mean {ratio.get('mean') or 0:.3f}, "
            f"max {ratio.get('max') or 0:.3f}",
            f"area change: mean {100 * (change.get('mean') or 0):.1f}%, "
            f"p95 {100 * (change.get('p95') or 0):.1f}%, max {100 * (change.get('max') or 0):.1f}%",
            f"iterations: {self.result.iterations} "
            f"({'converged' if self.result.converged else self.result.stop_reason})",
            f"time: solve {1000 * total:.0f} ms, last re-solve {1000 * self.solve_seconds:.0f} ms",
        ]
        if self.solver is not None:
            lines.append(f"factorizations: {self.solver.factorizations}")
        if self.pending:
            lines.append("pending: " + ", ".join(f"{k}={v}" for k, v in self.pending.items()))
        return lines

    def warnings(self) -> list[str]:
        """The current result's quality warnings, one line each, as the panel shows them.

        ``["no quality warnings"]`` for a clean join, else a count line and
        ``"code: message"`` per warning (``docs/warnings.md``).
        """
        found = list(getattr(self.result, "warnings", ()))
        if not found:
            return ["no quality warnings"]
        many = "s" if len(found) != 1 else ""
        return [f"{len(found)} quality warning{many}:"] + [f"{w.code}: {w.message}" for w in found]

    # -- saving -----------------------------------------------------------------------------

    def _next_path(self, stem: str, suffix: str) -> Path:
        self.output_dir.mkdir(parents=True, exist_ok=True)
        k = 0
        while (self.output_dir / f"{stem}_{k:03d}{suffix}").exists():
            k += 1
        return self.output_dir / f"{stem}_{k:03d}{suffix}"

    def save_screenshot(self, path: str | os.PathLike | None = None) -> Path:
        """Save the current view (without the panel) as PNG; returns the path."""
        PIL = pillow()
        target = Path(path) if path is not None else self._next_path("igljoin_screenshot", ".png")
        buf = self.ps.screenshot_to_buffer(transparent_bg=False)
        with atomic_path(target) as tmp:
            PIL.Image.fromarray(buf[:, :, :3].copy()).save(tmp, format="PNG")
        self.message = f"saved {target}"
        return target

    def save_picture(self, path: str | os.PathLike | None = None, view: str = "both") -> Path:
        """Save the headless picture of the current result (see :func:`igljoin.viz.render`)."""
        target = Path(path) if path is not None else self._next_path("igljoin_picture", ".png")
        render(self.result, target, view=view, title=self.title, limit=self.limit)
        self.message = f"saved {target}"
        return target

    def save_result(self, folder: str | os.PathLike | None = None) -> Path:
        """Save the current result into a folder; returns the folder.

        Uses ``result.save(folder)`` (guest, welded mesh and report; without
        the welded mesh if welding fails). A result without ``save`` writes
        the deformed guest as ``guest.ply`` and the report as ``report.json``.
        """
        target = Path(folder) if folder is not None else self._next_path("igljoin_result", "")
        target.mkdir(parents=True, exist_ok=True)
        save = getattr(self.result, "save", None)
        if callable(save):
            try:
                save(target)
            except WeldError as exc:  # keep what can be kept: guest and report
                save(target, merged=False)
                self.message = f"saved {target} without the welded mesh ({exc})"
                return target
        else:
            write_mesh(target / "guest.ply", self.result.guest)
            atomic_write_text(
                target / "report.json", json.dumps(self.result.report(), indent=2) + "\n"
            )
        self.message = f"saved {target}"
        return target

    # -- the panel --------------------------------------------------------------------------

    def _ui(self, fn: Any, *args: Any, **kwargs: Any) -> Any:
        """Call a session method from the panel; errors are shown, not raised."""
        try:
            return fn(*args, **kwargs)
        except (IgljoinError, OSError, RuntimeError) as exc:
            self.message = str(exc)
            return None

    def frame(self) -> None:
        """The ImGui callback: draw the panel and route its changes to the methods above."""
        import polyscope.imgui as psim

        self.frames += 1
        opt = self.options
        psim.PushItemWidth(170)
        psim.TextUnformatted(self.title)
        psim.TextUnformatted(
            f"area change: blue shrink, white none, red stretch (full at {self.limit:g}x)"
        )
        psim.Separator()
        changed, live = psim.Checkbox("re-solve live", self.live)
        if changed:
            self.live = live
        changed, on = psim.Checkbox("smooth-join term", bool(opt.smooth))
        if changed:
            self._ui(self.set_smooth, on)
        log = psim.ImGuiSliderFlags_Logarithmic
        for name, option in WEIGHTS.items():
            lo, hi = WEIGHT_RANGES[name]
            changed, v = psim.SliderFloat(
                f"{name} weight", getattr(opt, option), lo, hi, "%.3g", log
            )
            if changed:
                self._ui(self.set_weight, name, v, resolve=False)
            if psim.IsItemDeactivatedAfterEdit() and self.live:
                self._ui(self.resolve)
        changed, n = psim.SliderInt(
            "max iterations", opt.max_iterations, *ITERATION_RANGE, "%d", log
        )
        if changed:
            self._ui(self.set_iterations, n, resolve=False)
        if psim.IsItemDeactivatedAfterEdit() and self.live:
            self._ui(self.resolve)
        if psim.Button("re-solve" + (" (pending)" if self.pending else "")):
            self._ui(self.resolve)
        psim.Separator()
        for line in self.figures():
            psim.TextUnformatted(line)
        lines = self.warnings()
        if getattr(self.result, "warnings", ()):
            psim.TextColored(WARNING_RGBA, lines[0])
            for line in lines[1:]:
                psim.TextWrapped("- " + line)  # messages are long: wrapped to the panel
        else:
            psim.TextUnformatted(lines[0])
        psim.Separator()
        names = list(self.scene.available_quantities)
        current = names.index(self.scene.quantity) if self.scene.quantity in names else 0
        changed, k = psim.Combo("colour by", current, names)
        if changed:
            self._ui(self.set_quantity, names[k])
        changed, flag = psim.Checkbox("original guest", self.scene.rest.is_enabled())
        if changed:
            self.show_rest(flag)
        changed, flag = psim.Checkbox("cross-seam tangents", self.scene.tangents)
        if changed:
            self.show_tangents(flag)
        changed, flag = psim.Checkbox(
            "welded mesh", self.scene.merged is not None and self.scene.merged.is_enabled()
        )
        if changed:
            self.show_merged(flag)
        for view in VIEWS:
            if psim.Button(f"{view} view"):
                self.look(view)
            psim.SameLine()
        psim.NewLine()
        if psim.Button("save screenshot"):
            self._ui(self.save_screenshot)
        psim.SameLine()
        if psim.Button("save picture"):
            self._ui(self.save_picture)
        psim.SameLine()
        if psim.Button("save result"):
            self._ui(self.save_result)
        if self.message:
            psim.TextUnformatted(self.message)
        psim.PopItemWidth()

    def close(self) -> None:
        """Remove the session's structures and its panel callback (once; later calls do nothing)."""
        if self in _ACTIVE:
            _ACTIVE.remove(self)
        if self.scene is not None:
            self.ps.clear_user_callback()
            self.scene.remove()
            self.scene = None


def inspect(
    source: Any,
    *,
    show: bool = True,
    title: str | None = None,
    limit: float = colors.AREA_RATIO_LIMIT,
    output_dir: str | os.PathLike = ".",
) -> Session:
    """Open an interactive inspection of a join.

    Parameters
    ----------
    source : JoinSolver or JoinResult
        A solver can be re-solved live from the panel; a result too, after a
        solver is rebuilt from it on the first re-solve.
    show : bool
        Open the window and block until it is closed (``ps.show()``). With
        ``False`` the session is set up and returned, and the caller drives
        frames with ``polyscope.frame_tick()``.
    title : str, optional
        Case name shown in the panel and saved pictures.
    limit : float
        Area ratio drawn at full colour.
    output_dir : str or os.PathLike
        Where the save buttons write.

    Returns
    -------
    Session
        Its methods make the panel's changes from a script. A new ``inspect``
        closes the previous session (the structures' names are shared).

    Raises
    ------
    RuntimeError
        If ``show`` is true but polyscope runs headless (no display, or it
        was initialised off-screen earlier in this process): the window
        could never open and ``ps.show()`` would not return.
    """
    ps = ensure_init()
    if show and is_headless():
        raise RuntimeError(
            "inspect(show=True) needs a display, but polyscope runs headless in this process "
            "(no DISPLAY, or igljoin.viz.render() initialised it off-screen first); use "
            "inspect(..., show=False) and polyscope.frame_tick(), or igljoin.viz.render()"
        )
    for previous in list(_ACTIVE):  # structure names are shared: one session at a time
        previous.close()
    session = Session(source, title=title, limit=limit, output_dir=output_dir)
    _ACTIVE.append(session)
    ps.set_user_callback(session.frame)
    session.look("side")
    if show:
        ps.show()
    return session
