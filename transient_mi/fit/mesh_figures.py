"""The three-view figure of ``transient-mi fit --model mesh`` (``views.png``): start, fit and ground truth, each
seen from the wall (front, along +z), from above and from the side (both 30 degrees oblique, so that a plane
seen edge-on still shows), orthographic, flat-shaded by the face normal's angle to the view (painter's order:
far faces first); the same axes for every row (the union of the meshes' extents)."""

from __future__ import annotations

import numpy as np

__all__ = ["three_view_figure"]

def _camera(d, up):
    d = np.asarray(d, dtype=np.float64)
    d /= np.linalg.norm(d)
    right = np.cross(d, up)
    right /= np.linalg.norm(right)
    return d, right, np.cross(right, d)


_C30, _S30 = np.cos(np.radians(30)), np.sin(np.radians(30))
#: (title, viewing direction, screen up): world x right, y up, the hidden space at z > 0 (the wall at z = 0)
_VIEWS = (("front (from the wall)", (0.0, 0.0, 1.0), np.array([0.0, 1.0, 0.0])),
          ("top, 30 deg oblique", (0.0, -_C30, _S30), np.array([0.0, 0.0, 1.0])),
          ("side, 30 deg oblique", (_C30, 0.0, _S30), np.array([0.0, 1.0, 0.0])))


def _project(v, view):
    d, r, u = _camera(view[1], view[2])
    return np.stack([v @ r, v @ u], axis=-1), v @ d


def _draw(ax, v, f, view) -> None:
    from matplotlib.collections import PolyCollection

    v = np.asarray(v, dtype=np.float64)
    f = np.asarray(f, dtype=np.int64)
    tri = v[f]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
    d = _camera(view[1], view[2])[0]
    shade = 0.25 + 0.75 * np.abs(n @ d)
    p2, depth = _project(tri, view)
    order = np.argsort(-depth.mean(axis=1))  # far (large along the view direction) first
    poly = p2[order]
    col = np.repeat(shade[order, None], 3, axis=1) * np.array([0.55, 0.7, 0.9])
    ax.add_collection(PolyCollection(poly, facecolors=col, edgecolors="none"))


def three_view_figure(path, meshes: list, labels: list[str]) -> None:
    """``meshes``: ``(vertices [V, 3] m, faces [F, 3])`` or None (a missing panel) per row, ``labels`` the rows'
    titles."""
    from transient_mi.reporting import save_figure, subplots

    pts = np.concatenate([np.asarray(m[0], dtype=np.float64) for m in meshes if m is not None])
    fig, axes = subplots(len(meshes), 3, figsize=(9.0, 3.3 * len(meshes)))
    axes = np.asarray(axes).reshape(len(meshes), 3)
    for c, view in enumerate(_VIEWS):
        p2, _ = _project(pts, view)
        lo, hi = p2.min(axis=0), p2.max(axis=0)
        pad = 0.05 * float(np.max(hi - lo)) + 1e-3
        for r, (mesh, label) in enumerate(zip(meshes, labels)):
            ax = axes[r, c]
            if mesh is not None:
                _draw(ax, mesh[0], mesh[1], view)
            ax.set_xlim(lo[0] - pad, hi[0] + pad)
            ax.set_ylim(lo[1] - pad, hi[1] + pad)
            ax.set_aspect("equal")
            ax.set_title(f"{label}: {view[0]}", fontsize=8)
            ax.tick_params(labelsize=6)
    save_figure(fig, path, dpi=100)
