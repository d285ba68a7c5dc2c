"""Pictures of the simulation check report: 2D plots (matplotlib, Agg) and shell renders.

Shell renders use pyvista off-screen (Mesa EGL, z-buffered shading).  Whether
pyvista can render is probed once per process in a *subprocess*, because a
missing EGL/OpenGL stack can abort the interpreter instead of raising; when it
cannot, :class:`ShellRenderer` falls back to matplotlib 3D (no depth buffer:
overlapping parts may be drawn in the wrong order) and the report says so.

Geometry drawn: every base is two cylinders (top layer z in [0, 2.3] in amber,
bottom layer z in [-2.3, 0] in blue, in the base's flat frame) placed by the
frame's ``base_center`` and ``base_rotation``; the membrane is its triangle
mesh in light grey.
"""

from __future__ import annotations

import functools
import os
import subprocess
import textwrap
import threading

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection, PatchCollection  # noqa: E402
from matplotlib.patches import Circle  # noqa: E402

from pysolver.core.child import python_argv  # noqa: E402
from pysolver.params import LIMITS, UNIT_CELL  # noqa: E402

TOP_COLOR = "#e8a33d"
BOTTOM_COLOR = "#3d7be8"
MEMBRANE_COLOR = "#d0d0d0"
DPI = 100

_EGL_ENV = {"VTK_DEFAULT_OPENGL_WINDOW": "vtkEGLRenderWindow"}

_PROBE = """
import pyvista as pv
p = pv.Plotter(off_screen=True, window_size=(64, 48))
p.add_mesh(pv.Sphere())
img = p.screenshot(return_img=True)
p.close()
assert img.shape[0] == 48 and img.std() > 0
print("ok")
"""


_PROBE_LOCK = threading.Lock()  # one probe; a second caller waits for its result


def pyvista_status() -> tuple[bool, str]:
    """Whether pyvista renders off-screen here: ``(ok, reason)``; probed once, in a subprocess
    (a Python start, VTK's import and one off-screen render: 1-3 s of mostly waiting, which
    :func:`start_pyvista_probe` moves off the report's critical path)."""
    with _PROBE_LOCK:
        return _pyvista_status()


def start_pyvista_probe() -> threading.Thread:
    """Probe :func:`pyvista_status` in a background thread (the build starts it with the
    build, so the report stage reads the memoised result instead of waiting for the probe)."""
    th = threading.Thread(target=pyvista_status, name="pyvista-probe", daemon=True)
    th.start()
    return th


@functools.lru_cache(maxsize=1)
def _pyvista_status() -> tuple[bool, str]:
    try:
        import pyvista  # noqa: F401  (optional heavy dependency: probed, VTK rendering)
    except Exception as e:  # soft dependency
        return False, f"pyvista not importable ({type(e).__name__}: {e}); pip install pyvista"
    env = dict(os.environ)
    for k, v in _EGL_ENV.items():
        env.setdefault(k, v)
    try:
        r = subprocess.run(python_argv(code=_PROBE), env=env, capture_output=True,
                           text=True, timeout=LIMITS.probe_timeout_s)
    except (OSError, subprocess.TimeoutExpired) as e:
        return False, f"pyvista probe failed ({type(e).__name__})"
    if r.returncode != 0 or "ok" not in r.stdout:
        tail = (r.stderr or r.stdout).strip().splitlines()[-1:] or ["no output"]
        return False, f"pyvista off-screen rendering failed: {tail[0][:200]}"
    return True, "pyvista off-screen (EGL)"


def _import_pyvista():
    for k, v in _EGL_ENV.items():
        os.environ.setdefault(k, v)
    import pyvista as pv  # optional heavy dependency: VTK rendering only for 3D pictures

    pv.OFF_SCREEN = True
    return pv


def fit_titles(fig, width_chars: int = 200) -> int:
    """Wrap every axes title that sticks out of its figure onto more lines, then lay out.

    A title is measured with the figure's renderer; one that crosses the figure's left or
    right edge is wrapped at word boundaries, narrower each time, until it fits; the
    figure is then laid out again (``tight_layout``) so the extra lines stay inside.
    Returns the number of re-wraps (0 = nothing changed).
    """
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    box = fig.bbox
    n = 0
    for t in (ax.title for ax in fig.axes if ax.get_title()):
        text = t.get_text().replace("\n", " ")
        width = width_chars
        while width > 10:
            e = t.get_window_extent(r)
            if e.x0 >= box.x0 and e.x1 <= box.x1:
                break
            width = min(width, len(text)) - max(2, width // 6)
            t.set_text("\n".join(textwrap.wrap(text, max(width, 10))))
            fig.canvas.draw()
            n += 1
    if n:
        fig.tight_layout()
        fig.canvas.draw()
    return n


def titles_fit(fig) -> bool:
    """Every axes title lies inside the figure (nothing cut off)."""
    fig.canvas.draw()
    r = fig.canvas.get_renderer()
    box = fig.bbox
    for t in (ax.title for ax in fig.axes if ax.get_title()):
        e = t.get_window_extent(r)
        if e.x0 < box.x0 - 0.5 or e.x1 > box.x1 + 0.5 or e.y1 > box.y1 + 0.5:
            return False
    return True


def _save(fig, path):
    fit_titles(fig)
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


# --------------------------------------------------------------------------------------------
# kinematics helpers
# --------------------------------------------------------------------------------------------

def layer_templates(n_around=14):
    """Triangle meshes of one base's two layer cylinders in the base frame.

    Returns
    -------
    list of (points (m, 3) float mm, faces (k, 3) int), for (top, bottom).
    """
    r, h = UNIT_CELL.base_r, UNIT_CELL.layer_h
    a = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    ring = np.stack([r * np.cos(a), r * np.sin(a)], axis=1)
    out = []
    for z0, z1 in ((0.0, h), (-h, 0.0)):
        # side (own vertices, for smooth side normals), then the two caps (own vertices, flat)
        lo = np.column_stack([ring, np.full(n_around, z0)])
        hi = np.column_stack([ring, np.full(n_around, z1)])
        pts = np.concatenate([lo, hi, lo, hi, [[0, 0, z0], [0, 0, z1]]])
        n = n_around
        k = np.arange(n)
        k1 = (k + 1) % n
        side = np.concatenate([np.stack([k, k1, n + k1], 1), np.stack([k, n + k1, n + k], 1)])
        c_lo, c_hi = 4 * n, 4 * n + 1
        cap_lo = np.stack([np.full(n, c_lo), 2 * n + k1, 2 * n + k], 1)
        cap_hi = np.stack([np.full(n, c_hi), 3 * n + k, 3 * n + k1], 1)
        out.append((pts, np.concatenate([side, cap_lo, cap_hi]).astype(np.int64)))
    return out


def place(template_pts, C, R):
    """Template points placed at every base pose.

    Parameters
    ----------
    template_pts : (m, 3) float, mm
    C : (n_bases, 3) float, mm
    R : (n_bases, 3, 3) float

    Returns
    -------
    P : (n_bases * m, 3) float, mm
    """
    return (C[:, None, :] + np.einsum("bij,mj->bmi", R, template_pts)).reshape(-1, 3)


def view_frame(normals):
    """Camera direction and view-up for an oblique view of a shell with mean normal ``normals``.

    Returns
    -------
    d : (3,) float — unit vector from the focal point to the camera
    up : (3,) float — unit view-up
    """
    n = np.asarray(normals, float).reshape(-1, 3).mean(axis=0)
    if np.linalg.norm(n) < 0.3:
        n = np.array([0.0, 0.0, 1.0])
    n = n / np.linalg.norm(n)
    helper = np.array([1.0, 0.0, 0.0]) if abs(n[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    e1 = np.cross(n, helper)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(n, e1)
    el = np.radians(55.0)        # elevation above the shell's mean plane
    az = np.radians(-35.0)
    d = np.cos(el) * (np.cos(az) * e1 + np.sin(az) * e2) + np.sin(el) * n
    d /= np.linalg.norm(d)
    up = n - d * (n @ d)
    return d, up / np.linalg.norm(up)


# --------------------------------------------------------------------------------------------
# shell renderer
# --------------------------------------------------------------------------------------------

class ShellRenderer:
    """Renders frames of one shell with a fixed camera (pyvista, else matplotlib 3D).

    Parameters
    ----------
    C : (n_frames, n_bases, 3) float, mm
        Base centres (already in the display frame).
    R : (n_frames, n_bases, 3, 3) float
        Base rotations (display frame).
    M : (n_frames, n_mem, 3) float, mm, or None
        Membrane vertices.
    T : (n_tri, 3) int, or None
        Membrane triangles.
    normals : (n, 3) float
        Target normals, to choose the viewing direction.
    size : (int, int), px
        Image width and height.
    backend : {"auto", "pyvista", "matplotlib"}
    """

    def __init__(self, C, R, M=None, T=None, *, normals=None, size=(560, 420), backend="auto"):
        self.C, self.R, self.M, self.T = C, R, M, T
        self.size = (int(size[0]), int(size[1]))
        self.n_bases = C.shape[1]
        self.templates = layer_templates()
        self.dir, self.up = view_frame(normals if normals is not None else [[0, 0, 1]])
        self.lo, self.hi = self.bounds(range(C.shape[0]))
        self.note = ""
        if backend == "auto":
            ok, why = pyvista_status()
            self.backend = "pyvista" if ok else "matplotlib"
            if not ok:
                self.note = why
        else:
            self.backend = backend
        self._pl = None

    # -- geometry ------------------------------------------------------------------------------
    def bounds(self, frames):
        """Axis-aligned box (lo, hi) of the given frames, padded by a base's size."""
        frames = list(frames)
        pts = [self.C[frames].reshape(-1, 3)]
        if self.M is not None:
            pts.append(self.M[frames].reshape(-1, 3))
        allp = np.concatenate(pts)
        allp = allp[np.isfinite(allp).all(axis=1)]
        pad = UNIT_CELL.base_r + UNIT_CELL.layer_h
        return allp.min(axis=0) - pad, allp.max(axis=0) + pad

    def layer_points(self, f, layer):
        pts, _ = self.templates[layer]
        return place(pts, self.C[f], self.R[f])

    def layer_faces(self, layer):
        pts, faces = self.templates[layer]
        m = len(pts)
        return (faces[None, :, :] + m * np.arange(self.n_bases)[:, None, None]).reshape(-1, 3)

    # -- pyvista ------------------------------------------------------------------------------
    def _pv_setup(self, lo, hi, view, zoom, base_scalars=None, clim=None, cmap="viridis",
                  highlight=None, scalar_title="", extra_points=None):
        pv = _import_pyvista()
        # 8x MSAA (pyvista default) costs ~2x in software rendering (llvmpipe); FXAA falls back
        # to SSAA with EGL: no anti-aliasing
        theme = pv.themes.DocumentTheme()
        theme.multi_samples = 1
        theme.anti_aliasing = None
        pl = pv.Plotter(off_screen=True, window_size=self.size, theme=theme,
                        lighting="three lights")
        pl.set_background("white")
        meshes = []
        for layer in (0, 1):
            faces = self.layer_faces(layer)
            cells = np.hstack([np.full((len(faces), 1), 3), faces]).ravel()
            mesh = pv.PolyData(self.layer_points(0, layer), cells)
            per_base = len(self.templates[layer][1])
            kw = dict(smooth_shading=True, specular=0.2)
            if base_scalars is not None:
                mesh.cell_data["value"] = np.repeat(np.asarray(base_scalars, float), per_base)
                pl.add_mesh(mesh, scalars="value", cmap=cmap, clim=clim,
                            show_scalar_bar=(layer == 0),
                            scalar_bar_args=dict(title=scalar_title, vertical=True,
                                                 position_x=0.86, position_y=0.1, height=0.8,
                                                 width=0.08, color="black",
                                                 title_font_size=12, label_font_size=11),
                            **kw)
            elif highlight is not None:
                hl = np.zeros(self.n_bases)
                hl[np.asarray(highlight, int)] = 1.0
                mesh.cell_data["hit"] = np.repeat(hl, per_base)
                pl.add_mesh(mesh, scalars="hit", cmap=["#c8c8c8", "#e02020"], clim=(0, 1),
                            show_scalar_bar=False, **kw)
            else:
                pl.add_mesh(mesh, color=TOP_COLOR if layer == 0 else BOTTOM_COLOR, **kw)
            meshes.append(mesh)
        if self.M is not None and self.T is not None and len(self.T):
            tri = np.asarray(self.T, np.int64)
            cells = np.hstack([np.full((len(tri), 1), 3), tri]).ravel()
            mem = pv.PolyData(self.M[0], cells)
            pl.add_mesh(mem, color=MEMBRANE_COLOR, smooth_shading=True)
            meshes.append(mem)
        if extra_points is not None and len(extra_points):
            pl.add_points(np.asarray(extra_points, float), color="red", point_size=14,
                          render_points_as_spheres=True)
        focal = 0.5 * (lo + hi)
        dist = 3.0 * np.linalg.norm(hi - lo)
        d, up = view
        pl.camera_position = [tuple(focal + dist * d), tuple(focal), tuple(up)]
        pl.reset_camera(bounds=[lo[0], hi[0], lo[1], hi[1], lo[2], hi[2]])
        pl.camera.zoom(zoom)
        return pl, meshes

    def _pv_update(self, meshes, f):
        for layer in (0, 1):
            meshes[layer].points = self.layer_points(f, layer)
        if len(meshes) > 2:
            meshes[2].points = self.M[f]

    # -- matplotlib ---------------------------------------------------------------------------
    def _mpl_image(self, f, lo, hi, view, base_scalars=None, clim=None, cmap="viridis",
                   highlight=None, scalar_title="", extra_points=None):
        # optional heavy dependency: matplotlib loads only when a picture is drawn
        from mpl_toolkits.mplot3d.art3d import Poly3DCollection

        w, h = self.size
        fig = plt.figure(figsize=(w / DPI, h / DPI), dpi=DPI)
        ax = fig.add_axes((0, 0, 1, 1), projection="3d")
        r = UNIT_CELL.base_r
        a = np.linspace(0, 2 * np.pi, 6, endpoint=False)
        hexa = np.stack([r * np.cos(a), r * np.sin(a), np.zeros(6)], 1)
        polys, colors = [], []
        if base_scalars is not None:
            norm = matplotlib.colors.Normalize(*(clim or (np.nanmin(base_scalars),
                                                          np.nanmax(base_scalars))))
            cm = matplotlib.colormaps[cmap]
            base_col = cm(norm(np.asarray(base_scalars, float)))
        for layer, z in ((1, -UNIT_CELL.layer_h), (0, UNIT_CELL.layer_h)):
            P = place(hexa + [0, 0, z], self.C[f], self.R[f]).reshape(self.n_bases, 6, 3)
            polys.extend(P)
            if base_scalars is not None:
                colors.extend(base_col)
            elif highlight is not None:
                hl = np.zeros(self.n_bases, bool)
                hl[np.asarray(highlight, int)] = True
                colors.extend(np.where(hl[:, None], matplotlib.colors.to_rgba("#e02020"),
                                       matplotlib.colors.to_rgba("#c8c8c8")))
            else:
                c = matplotlib.colors.to_rgba(TOP_COLOR if layer == 0 else BOTTOM_COLOR)
                colors.extend([c] * self.n_bases)
        if self.M is not None and self.T is not None and len(self.T):
            ax.add_collection3d(Poly3DCollection(self.M[f][self.T], facecolor=MEMBRANE_COLOR,
                                                 edgecolor="none", alpha=0.6))
        ax.add_collection3d(Poly3DCollection(polys, facecolors=colors, edgecolor="k",
                                             linewidths=0.2))
        if extra_points is not None and len(extra_points):
            ep = np.asarray(extra_points)
            ax.scatter(ep[:, 0], ep[:, 1], ep[:, 2], s=60, c="red")
        mid = 0.5 * (lo + hi)
        half = 0.5 * (hi - lo).max()
        ax.set_xlim(mid[0] - half, mid[0] + half)
        ax.set_ylim(mid[1] - half, mid[1] + half)
        ax.set_zlim(mid[2] - half, mid[2] + half)
        d = view[0]
        ax.view_init(elev=np.degrees(np.arcsin(np.clip(d[2], -1, 1))),
                     azim=np.degrees(np.arctan2(d[1], d[0])))
        ax.set_axis_off()
        ax.set_box_aspect(None, zoom=1.3)
        if base_scalars is not None:
            sm = matplotlib.cm.ScalarMappable(norm=norm, cmap=cmap)
            fig.colorbar(sm, ax=ax, shrink=0.7, label=scalar_title)
        fig.canvas.draw()
        img = np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()
        plt.close(fig)
        return img

    # -- public -------------------------------------------------------------------------------
    def images(self, frames, *, labels=None, fit="all", normal=None, zoom=None, **style):
        """Render frames with one camera; returns (h, w, 3) uint8 images.

        ``labels`` are drawn top-left.  ``fit="all"`` frames the camera on the
        whole morph (same view for every image), ``fit="these"`` on ``frames``,
        ``fit=(lo, hi)`` on that box.  ``normal`` (3,) overrides the direction
        the view is taken from (default: the target's mean normal).  ``zoom`` overrides
        the camera zoom (pyvista; default 1.25 for ``"all"``, else 1.1).
        """
        frames = list(frames)
        if isinstance(fit, str):
            lo, hi = (self.lo, self.hi) if fit == "all" else self.bounds(frames)
        else:
            lo, hi = (np.asarray(x, float) for x in fit)
        view = (self.dir, self.up) if normal is None else view_frame([normal])
        out = []
        if self.backend == "pyvista":
            # the bounding sphere leaves room: zoom in, less for a single frame's box
            z = zoom if zoom is not None else (1.25 if fit == "all" else 1.1)
            pl, meshes = self._pv_setup(lo, hi, view, z, **style)
            try:
                for f in frames:
                    self._pv_update(meshes, f)
                    pl.render()
                    out.append(np.asarray(pl.screenshot(return_img=True))[..., :3].copy())
            finally:
                pl.close()
        else:
            out = [self._mpl_image(f, lo, hi, view, **style) for f in frames]
        if labels is not None:
            out = [_label(img, text) for img, text in zip(out, labels, strict=True)]
        return out


def _label(img, text):
    """Write ``text`` in the top-left corner of an image (Pillow)."""
    # optional heavy dependency: Pillow only for pictures
    from PIL import Image, ImageDraw, ImageFont

    im = Image.fromarray(np.ascontiguousarray(img))
    draw = ImageDraw.Draw(im)
    try:
        font = ImageFont.load_default(size=max(10, im.height // 24))
    except TypeError:  # Pillow < 10.1
        font = ImageFont.load_default()
    draw.text((6, 4), text, fill=(0, 0, 0), font=font)
    return np.asarray(im)


def save_png(img, path):
    from PIL import Image  # optional heavy dependency: Pillow only for pictures

    Image.fromarray(np.ascontiguousarray(img)).save(path, optimize=True)
    return path


def save_gif(images, path, *, frame_ms=120, hold_ms=1200):
    """Animated GIF (imageio, Pillow plugin), looping, the last frame held ``hold_ms``."""
    import imageio.v3 as iio  # optional heavy dependency: imageio only for the animation

    dur = [frame_ms] * len(images)
    dur[-1] = hold_ms
    iio.imwrite(path, np.stack(images), extension=".gif", duration=dur, loop=0)
    return path


# --------------------------------------------------------------------------------------------
# 2D plots
# --------------------------------------------------------------------------------------------

def plot_timing(path, t_star, t_done, t_end, *, clamped=None, sd=None):
    """Simulated completion vs programmed t* of every unit cell.

    Cells the temporal stage could program are dots, clamped ones (t* outside what
    0.30-0.65 mm brackets reach) open squares; never-completed cells are red crosses
    drawn on the t_end line.  With ``sd`` (c,) s, each completed cell carries a bar of
    +-1 predicted sd under the per-bracket thickness scatter.
    """
    t_star = np.asarray(t_star, float)
    t_done = np.asarray(t_done, float)
    done = np.isfinite(t_done)
    cl = np.zeros(len(t_star), bool) if clamped is None else np.asarray(clamped, bool)
    fig, ax = plt.subplots(figsize=(6.4, 5.0))
    hi = max(np.nanmax(t_star) if t_star.size else 1, t_end) * 1.05
    ax.plot([0, hi], [0, hi], color="0.5", lw=1, ls="--", label="simulated = programmed")
    ok = done & ~cl
    if sd is not None:
        bar = done & np.isfinite(np.asarray(sd, float))
        ax.errorbar(t_star[bar], t_done[bar], yerr=np.asarray(sd, float)[bar], fmt="none",
                    ecolor="0.6", elinewidth=0.7, alpha=0.6,
                    label="+-1 sd predicted for a print (bracket thickness scatter)")
    ax.scatter(t_star[ok], t_done[ok], s=12, alpha=0.7,
               label=f"programmable, completed ({ok.sum()})")
    if (done & cl).any():
        ax.scatter(t_star[done & cl], t_done[done & cl], s=22, facecolors="none",
                   edgecolors="tab:orange", label=f"clamped, completed ({(done & cl).sum()})")
    if (~done).any():
        ax.scatter(t_star[~done], np.full((~done).sum(), t_end), s=16, marker="x",
                   color="red", clip_on=False,
                   label=f"never completed, shown at t_end ({(~done).sum()})")
    ax.axhline(t_end, color="0.7", lw=0.8)
    ax.set_xlabel("programmed completion t* (s)")
    ax.set_ylabel("simulated completion (s)")
    ax.set_xlim(0, hi)
    ax.set_ylim(0, hi * 1.04)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left", fontsize=8)
    ax.set_title("completion time per unit cell: all cells")
    fig.tight_layout()
    return _save(fig, path)


def plot_solver(path, t, iters, residual, wall, converged, tol_residual):
    """Newton iterations, residual and wall time per step; non-converged steps in red."""
    t = np.asarray(t, float)
    bad = ~np.asarray(converged, bool)
    fig, axs = plt.subplots(3, 1, figsize=(6.4, 6.0), sharex=True)
    for ax, y, name in zip(axs, (iters, residual, wall),
                           ("Newton iterations", "residual (N)", "wall time (s)"), strict=True):
        y = np.asarray(y, float)
        ax.plot(t, y, lw=1)
        if bad.any():
            ax.scatter(t[bad], y[bad], color="red", s=12, zorder=3, label="not converged")
        ax.set_ylabel(name)
        ax.grid(alpha=0.3)
    pos = np.asarray(residual, float)
    if np.any(pos > 0):
        axs[1].set_yscale("log")
    axs[1].axhline(tol_residual, color="red", lw=0.8, ls="--", label="FAIL above")
    axs[1].legend(fontsize=8, loc="upper right")
    axs[2].set_xlabel("time (s)")
    axs[0].set_title("solver health per step")
    fig.tight_layout()
    return _save(fig, path)


def plot_shape_over_time(path, t, rms_t, size, th):
    """RMS distance of the base centres to the target per frame, with the WARN and FAIL
    limits (``th``: ReportThresholds, % of the target size ``size`` in mm)."""
    fig, ax = plt.subplots(figsize=(6.4, 3.4))
    ax.plot(t, rms_t, lw=1.2)
    for pct, c in ((th.shape_rms_warn_pct, "orange"), (th.shape_rms_fail_pct, "red")):
        ax.axhline(size * pct / 100, color=c, ls="--", lw=0.8, label=f"{pct:g} % of size")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("RMS distance to target (mm)")
    ax.set_title("base centres vs target (each frame aligned rigidly)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, path)


def plot_clearance(path, t, base_clear, mem_clear, tol, reach=None):
    """Smallest clearance between non-neighbouring bases (and membrane vs far bases) over time."""
    fig, ax = plt.subplots(figsize=(6.4, 3.6))
    t = np.asarray(t, float)
    shown = False
    for y, name, mk in ((base_clear, "base vs base (non-neighbours)", "o"),
                        (mem_clear, "membrane vs far base", "x")):
        if y is None:
            continue
        y = np.asarray(y, float)
        m = np.isfinite(y)
        if m.any():
            ax.plot(t[m], y[m], mk, ms=3 if mk == "o" else 5, mfc="none", label=name)
            shown = True
    if not shown:
        ax.text(0.5, 0.6, "no pair of parts that must not touch came near each other",
                ha="center", transform=ax.transAxes)
    ax.axhline(0.0, color="0.4", lw=0.8)
    ax.axhline(-tol, color="red", lw=0.8, ls="--", label=f"collision (depth > {tol:g} mm)")
    ax.set_xlim(t[0], t[-1] if t[-1] > t[0] else t[0] + 1)
    ax.set_xlabel("time (s)")
    ax.set_ylabel("min clearance (mm)")
    ax.set_title("closest approach of parts that must not touch" + (
        f"\n(pairs with centres closer than {reach:.1f} mm; no point = none that close)"
        if reach else ""), fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    return _save(fig, path)


def _bases_patches(ax, xy, r, color="0.75"):
    pc = PatchCollection([Circle(p, r) for p in xy], facecolor=color, edgecolor="0.4",
                         linewidths=0.3)
    ax.add_collection(pc)


def plot_layout_thickness(path, flat_xy, cells_ab, th_top, th_bottom):
    """Flat layout: bases as discs, unit cells as segments coloured by bracket thickness."""
    flat_xy = np.asarray(flat_xy, float)
    seg = flat_xy[np.asarray(cells_ab, int)]
    vals = [np.asarray(th_top, float), np.asarray(th_bottom, float)]
    allv = np.concatenate(vals)
    lo = UNIT_CELL.thickness_min if allv.size == 0 else min(UNIT_CELL.thickness_min,
                                                            np.nanmin(allv))
    hi = UNIT_CELL.thickness_max if allv.size == 0 else max(UNIT_CELL.thickness_max,
                                                            np.nanmax(allv))
    fig, axs = plt.subplots(1, 2, figsize=(10, 4.8))
    for ax, v, name in zip(axs, vals, ("top layer", "bottom layer"), strict=True):
        _bases_patches(ax, flat_xy, UNIT_CELL.base_r)
        lc = LineCollection(seg, array=v, cmap="viridis", linewidths=3)
        lc.set_clim(lo, hi)
        ax.add_collection(lc)
        ax.set_aspect("equal")
        ax.autoscale_view()
        ax.set_title(f"bracket thickness, {name}")
        ax.set_xlabel("x (mm)")
    axs[0].set_ylabel("y (mm)")
    fig.colorbar(lc, ax=axs, shrink=0.8, label="thickness (mm)")
    return _save(fig, path)


def plot_time_landscape(path, flat_xy, cells_ab, t_star, t_done, *, uv=None, faces=None,
                        landscape=None, t_end=None):
    """Programmed time landscape (flat) beside the simulated completion time per cell."""
    flat_xy = np.asarray(flat_xy, float)
    mid = flat_xy[np.asarray(cells_ab, int)].mean(axis=1)
    t_done = np.asarray(t_done, float)
    vals = [np.asarray(t_star, float), t_done[np.isfinite(t_done)]]
    if landscape is not None:
        vals.append(np.asarray(landscape, float))
    allv = np.concatenate([v for v in vals if v.size])
    vmin, vmax = (float(np.nanmin(allv)), float(np.nanmax(allv))) if allv.size else (0, 1)
    if vmax <= vmin:
        vmax = vmin + 1.0
    fig, axs = plt.subplots(1, 2, figsize=(10, 4.8))
    ax = axs[0]
    if uv is not None and faces is not None and landscape is not None:
        m = ax.tripcolor(uv[:, 0], uv[:, 1], faces, landscape, shading="gouraud",
                         cmap="viridis", vmin=vmin, vmax=vmax)
        ax.triplot(uv[:, 0], uv[:, 1], faces, color="w", lw=0.3, alpha=0.5)
        ax.set_title("programmed time landscape (s)")
    else:
        m = ax.scatter(mid[:, 0], mid[:, 1], c=t_star, cmap="viridis", vmin=vmin, vmax=vmax,
                       s=25)
        ax.set_title("programmed t* per cell (s)")
    ax = axs[1]
    _bases_patches(ax, flat_xy, UNIT_CELL.base_r, color="0.9")
    ok = np.isfinite(t_done)
    ax.scatter(mid[ok, 0], mid[ok, 1], c=t_done[ok], cmap="viridis", vmin=vmin, vmax=vmax,
               s=25, edgecolors="none")
    if (~ok).any():
        ax.scatter(mid[~ok, 0], mid[~ok, 1], marker="x", color="red", s=25,
                   label="never completed")
        ax.legend(fontsize=8, loc="upper right")
    ax.set_title("simulated completion per cell (s)")
    for a in axs:
        a.set_aspect("equal")
        a.autoscale_view()
        a.set_xlabel("x (mm)")
    axs[0].set_ylabel("y (mm)")
    fig.colorbar(m, ax=axs, shrink=0.8, label="time (s)")
    return _save(fig, path)


__all__ = ["ShellRenderer", "pyvista_status", "start_pyvista_probe", "layer_templates", "place",
           "plot_shape_over_time",
           "view_frame",
           "save_png", "save_gif", "plot_timing", "plot_solver", "plot_clearance",
           "plot_layout_thickness", "plot_time_landscape", "fit_titles", "titles_fit"]
