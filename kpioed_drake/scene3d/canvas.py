"""Drawing primitives on a Drake ``Meshcat`` and its export to one self-contained HTML page.

:class:`Canvas` owns one :class:`pydrake.geometry.Meshcat` (a local websocket server bound to
``localhost``), draws into it in millimetres (Meshcat uses metres), and exports the scene with
``Meshcat.StaticHtml()``: meshcat's JavaScript is inlined and every scene command is a ``data:``
URL, so the page opens without network access. An overlay (title, colour key, notes and a
per-pose table) is added to the page as plain HTML.

Poses are stepped through by a :class:`pydrake.geometry.MeshcatAnimation` of the ``visible``
property: frame k (time k s at one frame per second) shows the group of pose k only.
"""

from __future__ import annotations

import html
import logging
import re

import numpy as np
from numpy.typing import ArrayLike
from pydrake.geometry import (
    Box,
    Cylinder,
    Ellipsoid,
    Meshcat,
    MeshcatAnimation,
    MeshcatCone,
    MeshcatParams,
    Rgba,
    Shape,
    Sphere,
)
from pydrake.math import RigidTransform, RotationMatrix

from kpioed_drake.robot.plant import MM, capsule_pose

ROBOT = Rgba(1.0, 0.42, 0.0, 1.0)
"""Robot colour (feasible poses): KUKA orange."""
INFEASIBLE = Rgba(0.85, 0.0, 0.1, 1.0)
"""Robot colour of an infeasible pose."""
BEAM = Rgba(0.05, 0.8, 0.1, 1.0)
"""The laser beam from the tracker to the reflector."""
CLEARANCE = Rgba(0.95, 0.0, 0.95, 1.0)
"""The shortest distance of a pose to a collision (a line between the two closest points)."""
TRACKER = Rgba(0.15, 0.15, 0.18, 1.0)
"""The laser tracker."""
CAR = Rgba(0.55, 0.58, 0.6, 0.45)
"""The car's capsules (translucent)."""
MOUNT = Rgba(0.45, 0.45, 0.45, 1.0)
"""The mount the robot stands on."""
WALL = Rgba(0.9, 0.9, 0.85, 0.3)
"""The wall behind the robot (translucent)."""
FLOOR = Rgba(0.78, 0.78, 0.74, 1.0)
"""The floor."""
WORK = Rgba(0.2, 0.5, 1.0, 0.3)
"""The working pose's robot (translucent blue)."""
ELLIPSOID = Rgba(0.0, 0.8, 0.9, 0.75)
"""The TCP's confidence ellipsoid at the working pose."""
COMPARE = Rgba(0.6, 0.45, 0.85, 0.7)
"""A second design or model drawn for comparison."""
AXES = (Rgba(0.9, 0.1, 0.1, 1.0), Rgba(0.1, 0.75, 0.1, 1.0), Rgba(0.1, 0.2, 0.9, 1.0))
"""The colours of a frame's x, y and z axes (red, green, blue)."""

_URL = re.compile(
    r"""(?:src|href)\s*=\s*["']?\s*(?:https?:|wss?:|//)|url\(\s*["']?\s*(?:https?:|//)|@import"""
)
_SCRIPT_BODY = re.compile(r"(<script[^>]*>).*?(</script>)", re.DOTALL | re.IGNORECASE)


def css(rgba: Rgba) -> str:
    """CSS colour of an Rgba."""
    return f"rgba({rgba.r() * 255:.0f},{rgba.g() * 255:.0f},{rgba.b() * 255:.0f},{max(rgba.a(), 0.6):.2f})"


def external_references(page: str) -> list[str]:
    """Markup in ``page`` that would load a resource from the network when the page opens.

    Looks, outside the bodies of ``<script>`` elements, for ``src=``/``href=`` attributes and CSS
    ``url(...)`` with an ``http(s)``, ``ws(s)`` or protocol-relative target, and for CSS
    ``@import`` (a ``<script src=...>`` tag itself is markup and is found). What the inlined
    JavaScript requests at run time is not visible here: the browser test records the requests.
    """
    markup = _SCRIPT_BODY.sub(r"\1\2", page)
    return [m.group(0) for m in _URL.finditer(markup)]


def _nice(x: float) -> float:
    """Largest 1, 2 or 5 times a power of ten that is at most ``x`` (> 0)."""
    e = 10.0 ** np.floor(np.log10(x))
    return float(max(m for m in (1.0, 2.0, 5.0) if m * e <= x) * e)


def nice_scale(longest_mm: float, target_mm: float) -> float:
    """A round magnification (1, 2, 5 x 10^k) that draws ``longest_mm`` at about ``target_mm``."""
    if not np.isfinite(longest_mm) or longest_mm <= 0:
        return 1.0
    return _nice(target_mm / longest_mm)


class Canvas:
    """One Meshcat scene drawn in millimetres; use as a context manager (frees the server's port).

    Args:
        title: page title (also the overlay's heading).
    """

    def __init__(self, title: str):
        drake_log = logging.getLogger("drake")
        level = drake_log.level
        drake_log.setLevel(logging.WARNING)  # no "Meshcat listening ..." line per page
        try:
            self.meshcat = Meshcat(MeshcatParams(host="localhost", port=0))  # an ephemeral port
        finally:
            drake_log.setLevel(level)
        for path in ("/Grid", "/Axes"):  # the scene draws its own floor
            self.hide(path)
        self.title = title
        self.legend: list[tuple[str, str]] = []
        self.notes: list[str] = []
        self.table: tuple[list[str], list[list[str]]] | None = None
        self._groups: list[str] = []

    def __enter__(self) -> Canvas:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Stop the Meshcat server (idempotent)."""
        self.meshcat = None

    # ------------------------------------------------------------------------------------------
    # Primitives [mm]
    # ------------------------------------------------------------------------------------------
    def shape(self, path: str, shape: Shape, X_WG: RigidTransform, rgba: Rgba) -> None:
        """A Drake shape already in metres at pose ``X_WG`` (metres)."""
        self.meshcat.SetObject(path, shape, rgba)
        self.meshcat.SetTransform(path, X_WG)

    def sphere(self, path: str, p_W: ArrayLike, radius: float, rgba: Rgba) -> None:
        """Sphere of ``radius`` [mm] at ``p_W`` (3,) [mm]."""
        self.shape(path, Sphere(radius * MM), RigidTransform(np.asarray(p_W, float) * MM), rgba)

    def rod(self, path: str, a: ArrayLike, b: ArrayLike, radius: float, rgba: Rgba) -> None:
        """Cylinder from ``a`` to ``b`` (3,) [mm] of ``radius`` [mm] (nothing if a == b)."""
        X, length = capsule_pose(a, b)
        if length > 1e-6:
            self.shape(path, Cylinder(radius * MM, length), X, rgba)

    def arrow(self, path: str, a: ArrayLike, b: ArrayLike, radius: float, rgba: Rgba) -> None:
        """Arrow from ``a`` to ``b`` [mm]: a rod and a cone head of length 4 radii (up to half)."""
        a, b = np.asarray(a, float), np.asarray(b, float)
        length = float(np.linalg.norm(b - a))
        if length <= 1e-6:
            return
        u = (b - a) / length
        head = min(4.0 * radius, 0.5 * length)
        self.rod(f"{path}/shaft", a, b - head * u, radius, rgba)
        R = RotationMatrix.MakeFromOneVector(-u, 2)  # MeshcatCone: apex at the origin, opens along +z
        cone = MeshcatCone(head * MM, 2.0 * radius * MM, 2.0 * radius * MM)
        self.shape(f"{path}/head", cone, RigidTransform(R, b * MM), rgba)

    def ellipsoid(self, path: str, centre: ArrayLike, C: np.ndarray, k: float, rgba: Rgba) -> np.ndarray:
        """Ellipsoid ``x^T C^-1 x = k^2`` around ``centre`` [mm]; returns its semi-axes (3,) [mm]."""
        w, V = np.linalg.eigh(0.5 * (C + C.T))
        V = V * np.sign(np.linalg.det(V))  # proper rotation
        semi = k * np.sqrt(np.maximum(w, 0.0))
        shape = Ellipsoid(*np.maximum(semi * MM, 1e-6))
        self.shape(path, shape, RigidTransform(RotationMatrix(V), np.asarray(centre, float) * MM), rgba)
        return semi

    def box(self, path: str, lo: ArrayLike, hi: ArrayLike, rgba: Rgba) -> None:
        """Axis-aligned box between corners ``lo`` and ``hi`` (3,) [mm]."""
        lo, hi = np.asarray(lo, float), np.asarray(hi, float)
        self.shape(path, Box(*((hi - lo) * MM)), RigidTransform(0.5 * (lo + hi) * MM), rgba)

    def oriented_box(self, path: str, size: ArrayLike, R_WB: np.ndarray, p_WB: ArrayLike, rgba: Rgba) -> None:
        """Box of edge lengths ``size`` (3,) [mm] along the columns of ``R_WB`` (3, 3), centred at
        ``p_WB`` (3,) [mm]."""
        shape = Box(*(np.asarray(size, float) * MM))
        self.shape(path, shape, RigidTransform(RotationMatrix(R_WB), np.asarray(p_WB, float) * MM), rgba)

    def triad(
        self, path: str, R_WF: np.ndarray, p_WF: ArrayLike, length: float, radius: float, alpha: float = 1.0
    ) -> None:
        """Frame F as three axes (x red, y green, z blue) of ``length`` and ``radius`` [mm] and
        opacity ``alpha``: the group ``path`` posed at ``R_WF`` (3, 3), ``p_WF`` (3,) [mm], its axes
        ``path/x``, ``path/y``, ``path/z`` in F."""
        self.meshcat.SetTransform(path, RigidTransform(RotationMatrix(R_WF), np.asarray(p_WF, float) * MM))
        for i, c in enumerate(AXES):
            rgba = Rgba(c.r(), c.g(), c.b(), alpha)
            self.rod(f"{path}/{'xyz'[i]}", np.zeros(3), length * np.eye(3)[i], radius, rgba)

    def hide(self, path: str) -> None:
        self.meshcat.SetProperty(path, "visible", False)

    def camera(self, p_WC: ArrayLike, p_WTarget: ArrayLike) -> None:
        """Initial camera at ``p_WC`` looking at ``p_WTarget`` [mm]."""
        self.meshcat.SetCameraPose(np.asarray(p_WC, float) * MM, np.asarray(p_WTarget, float) * MM)

    # ------------------------------------------------------------------------------------------
    # Pose groups, animation, export
    # ------------------------------------------------------------------------------------------
    def group(self, k: int) -> str:
        """Path of the group of pose ``k`` (0-based); register groups in order 0, 1, ..."""
        path = f"/poses/pose {k + 1:03d}"
        if k == len(self._groups):
            self._groups.append(path)
        return path

    def animate_groups(self, start: int = 0) -> None:
        """Frame k shows pose group k only (one frame per second, paused); the page opens at ``start``."""
        anim = MeshcatAnimation(frames_per_second=1.0)
        anim.set_autoplay(False)
        anim.set_loop_mode(MeshcatAnimation.LoopMode.kLoopRepeat)
        for k, path in enumerate(self._groups):
            self.meshcat.SetProperty(path, "visible", k == start)
            anim.SetProperty(0, path, "visible", k == 0)
            if k > 0:
                anim.SetProperty(k, path, "visible", True)
            if k + 1 < len(self._groups):
                anim.SetProperty(k + 1, path, "visible", False)
        if self._groups:
            self.meshcat.SetAnimation(anim)

    def html(self) -> str:
        """The self-contained page: Meshcat's static export with the overlay."""
        page = self.meshcat.StaticHtml()
        page = page.replace("<title>Drake MeshCat</title>", f"<title>{html.escape(self.title)}</title>", 1)
        head, sep, tail = page.rpartition("</body>")
        return head + self._overlay() + sep + tail if sep else page + self._overlay()

    def _overlay(self) -> str:
        e = html.escape
        items = "".join(
            f'<div><span class="sw" style="background:{colour}"></span>{e(text)}</div>'
            for colour, text in self.legend
        )
        notes = "".join(f"<div>{e(n)}</div>" for n in self.notes)
        table = ""
        if self.table is not None:
            header, rows = self.table
            th = "".join(f"<th>{e(h)}</th>" for h in header)
            tr = "".join("<tr>" + "".join(f"<td>{e(c)}</td>" for c in row) + "</tr>" for row in rows)
            table = f"<details><summary>poses</summary><table><tr>{th}</tr>{tr}</table></details>"
        return (
            "<style>#kpioed-key{position:fixed;left:8px;top:8px;max-width:30em;max-height:90vh;"
            "overflow:auto;background:rgba(255,255,255,.85);font:12px sans-serif;padding:6px 8px;"
            "border-radius:4px}#kpioed-key h1{font-size:14px;margin:0 0 4px}#kpioed-key .sw{"
            "display:inline-block;width:10px;height:10px;margin-right:5px;border:1px solid #555}"
            "#kpioed-key td,#kpioed-key th{padding:0 4px;text-align:right}</style>"
            f'<div id="kpioed-key"><h1>{e(self.title)}</h1>{items}{notes}{table}</div>'
        )
