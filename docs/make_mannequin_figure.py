"""Draw docs/img/mannequin.png and print the per-part table of docs/mannequin.md.

Run from the repository root:

    python docs/make_mannequin_figure.py [-o docs/img/mannequin.png]

Panels: the default mannequin seen from the wall (colour = depth z behind
the wall) and from its right side (colour = body part), the area-weighted
histogram of three-bounce arrival times of each part's wall-facing surface
for a laser spot and a wall point at the wall centre, and the other poses
seen from the wall. Everything is computed, nothing drawn by hand.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.patches  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402

from recon.ground_truth import ground_truth_depth_map  # noqa: E402
from transient_core.units import C_M_PER_PS  # noqa: E402
from transient_mi.scenes import mannequin as mq  # noqa: E402

GROUP_COLOURS = {"head": "#d62728", "neck": "#8c564b", "torso": "#7f7f7f", "arms": "#1f77b4", "legs": "#2ca02c"}


def _side(vertices: np.ndarray) -> np.ndarray:
    """World (x, y, z) -> (z, y, -x): looking from +x (the mannequin's right) towards -x."""
    return np.column_stack([vertices[:, 2], vertices[:, 1], -vertices[:, 0]])


def _part_map(parts: dict, u: np.ndarray, v: np.ndarray, transform=None) -> np.ndarray:
    """Index of the group seen first at each grid point (-1: nothing), axes [v, u]."""
    groups = list(mq.PART_GROUPS)
    best = np.full((v.size, u.size), np.inf)
    label = np.full((v.size, u.size), -1)
    for k, g in enumerate(groups):
        for name in mq.PART_GROUPS[g]:
            m = parts[name]
            verts = m.vertices if transform is None else transform(m.vertices)
            d = ground_truth_depth_map((verts, m.faces), u, v)
            closer = np.isfinite(d) & (d < best)
            best[closer] = d[closer]
            label[closer] = k
    return label


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", default="docs/img/mannequin.png")
    args = ap.parse_args()

    mesh = mq.make_mannequin()
    surf = mq.mannequin_parts(surface=True)
    groups = list(mq.PART_GROUPS)
    cmap_parts = ListedColormap([GROUP_COLOURS[g] for g in groups])

    step = 0.0025
    x = np.arange(-0.40, 0.40 + step / 2, step)
    y = np.arange(-0.45, 0.45 + step / 2, step)
    z = np.arange(0.30, 0.65 + step / 2, step)

    fig = plt.figure(figsize=(12.5, 8.0), dpi=90, layout="constrained")
    gs = fig.add_gridspec(2, 4, height_ratios=[1.2, 1.0])

    ax = fig.add_subplot(gs[0, 0])
    depth = ground_truth_depth_map(mesh, x, y)
    im = ax.imshow(100 * depth, origin="lower", extent=[x[0], x[-1], y[0], y[-1]], cmap="viridis_r")
    fig.colorbar(im, ax=ax, shrink=0.8, label="depth z (cm)")
    ax.set(title="default pose\n(depth seen from the wall)", xlabel="x (m)", ylabel="y (m)")

    ax = fig.add_subplot(gs[0, 1])
    lab = _part_map(surf, z, y, transform=_side)
    shown = np.ma.masked_less(lab, 0)
    ax.imshow(shown, origin="lower", extent=[z[0], z[-1], y[0], y[-1]], cmap=cmap_parts, vmin=0, vmax=len(groups) - 1,
              interpolation="nearest")
    ax.axvline(0.5, color="k", lw=0.6, ls=":")
    ax.set(title="default pose\n(parts, seen from its right)", xlabel="z (m); the wall is at z = 0, left", ylabel="y (m)")
    handles = [matplotlib.patches.Patch(color=GROUP_COLOURS[g], label=g) for g in groups]
    ax.legend(handles=handles, frameon=False, fontsize=7, loc="center right")

    ax = fig.add_subplot(gs[0, 2:])
    centre = np.zeros(3)
    edges = np.arange(2900.0, 4300.0, 20.0)
    for g in groups:
        m = mq.trimesh.util.concatenate([surf[n] for n in mq.PART_GROUPS[g]])
        sel = m.face_normals[:, 2] < 0
        o = m.triangles_center[sel]
        t = (np.linalg.norm(o - centre, axis=1) * 2) / C_M_PER_PS
        ax.hist(t, bins=edges, weights=1e4 * m.area_faces[sel], histtype="stepfilled", alpha=0.45,
                color=GROUP_COLOURS[g], label=g)
        ax.axvline(np.average(t, weights=m.area_faces[sel]), color=GROUP_COLOURS[g], lw=1.5)
    ax.set(title="three-bounce arrival, laser spot = wall point = wall centre\n"
                 "(hidden segments |S-o|+|o-P|; lines: area-weighted means)",
           xlabel="time of flight (ps)", ylabel="wall-facing area per 20 ps bin (cm²)")
    ax.legend(frameon=False)

    for k, pose in enumerate([p for p in mq.POSES if p != "arms_down"]):
        ax = fig.add_subplot(gs[1, k])
        d = ground_truth_depth_map(mq.make_mannequin(pose=pose), x, y)
        im = ax.imshow(100 * d, origin="lower", extent=[x[0], x[-1], y[0], y[-1]], cmap="viridis_r", vmin=20, vmax=55)
        ax.set(title=f"pose={pose}", xlabel="x (m)")
        if k == 0:
            ax.set_ylabel("y (m)")
    fig.colorbar(im, ax=fig.axes[-4:], shrink=0.8, label="depth z (cm)")

    fig.suptitle("transient-mi procedural mannequin (defaults: 0.60 m wide x 0.70 m tall, centre 0.5 m behind the wall)")
    out = Path(args.output)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=80, bbox_inches="tight")
    print(f"wrote {out} ({out.stat().st_size} bytes)")

    rep = mq.mannequin_part_report()
    print(f"\nrest arm angle {mq.rest_arm_angle_deg(0.7, 0.6):.1f} deg; {len(mesh.faces)} faces, {len(mesh.vertices)} vertices")
    print("\n| part | wall-facing area (cm²) | y range (m) | z min / mean / max (m) | mean arrival (ps) | range (ps) |")
    print("|---|---|---|---|---|---|")
    for g, r in rep.items():
        print(f"| {g} | {1e4 * r['area_m2']:.0f} | {r['y_min_m']:.3f} .. {r['y_max_m']:.3f} | "
              f"{r['z_min_m']:.3f} / {r['z_mean_m']:.3f} / {r['z_max_m']:.3f} | {r['t_mean_ps']:.0f} | "
              f"{r['t_min_ps']:.0f} .. {r['t_max_ps']:.0f} |")
    names = ["head", "arms", "legs", "torso"]
    print("\nmean arrival differences (ps):")
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            print(f"  {a} - {b}: {rep[a]['t_mean_ps'] - rep[b]['t_mean_ps']:+.0f}")


if __name__ == "__main__":
    main()
