"""Part meshing and antipodal grasp sampling per part, plus hand-guided part ranking.

Cases: surface samples (0.2 mm noise) of a 30×20×60 mm box with a few hundred to a few thousand
points, as the Gaussian centres of one part. `mesh` is the host-side alpha shape (Delaunay,
alpha sweep, Taubin smoothing, quadric decimation; no compile); `grasps` is the jitted sampler
(1000 rays, 10 base grasps → 480 poses), compile time apart; `rank` is the fingertip-contact
ranking over a short demo. Metrics check the geometry: volume error, extents, grasp widths.
"""

from __future__ import annotations

import jax
import numpy as np
import trimesh

from benchmarks._util import measure, record
from rsrd_jax.grasp import GraspResult, build_part_mesh, sample_antipodal_grasps
from rsrd_jax.hands import rank_parts

NAME = "grasp"
BOX = (0.03, 0.02, 0.06)


def _points(n: int, seed: int = 0) -> np.ndarray:
    pts, _ = trimesh.sample.sample_surface(trimesh.creation.box(BOX), n, seed=seed)
    return pts + np.random.default_rng(seed).normal(0.0, 2e-4, pts.shape)


def run(quick: bool) -> list[dict]:
    out = []
    sizes = [300, 1000] if quick else [300, 1000, 3000]
    repeat = 3 if quick else 5
    for n in sizes:
        pts = _points(n)
        compile_s, ms = measure(build_part_mesh, pts, repeat=repeat)
        mesh = build_part_mesh(pts)
        tm = mesh.to_trimesh()
        out.append(
            record(
                NAME,
                {"stage": "mesh", "points": n},
                ms,
                compile_s,
                {
                    "method": mesh.method,
                    "watertight": mesh.watertight,
                    "faces": len(mesh.faces),
                    "alpha_mm": mesh.alpha * 1e3,
                    "volume_rel_err": float(tm.volume / np.prod(BOX) - 1.0),
                    "extent_err_mm": float(np.abs(tm.extents - np.asarray(BOX)).max() * 1e3),
                },
            )
        )
        key = jax.random.key(0)
        compile_s, ms = measure(sample_antipodal_grasps, mesh, key, repeat=repeat)
        g = sample_antipodal_grasps(mesh, key)
        w = np.asarray(g.width)[np.asarray(g.valid)]
        werr = np.minimum(np.abs(w - 0.02), np.abs(w - 0.03)) if len(w) else np.zeros(1)
        out.append(
            record(
                NAME,
                {"stage": "grasps", "points": n, "faces": len(mesh.faces)},
                ms,
                compile_s,
                {
                    "success": bool(g.result == GraspResult.success),
                    "poses": int(np.asarray(g.valid).sum()),
                    "antipodal_candidates": int(g.num_antipodal),
                    "width_err_max_mm": float(werr.max() * 1e3),
                },
            )
        )

    # Ranking: 60 frames, 4 parts × 2000 points, two hands.
    rng = np.random.default_rng(1)
    T, P, N = 60, 4, 2000
    parts = [rng.uniform(-0.02, 0.02, (N, 3)) + [0.06 * p, 0.0, 0.0] for p in range(P)]
    poses = np.zeros((T, P, 7), np.float32)
    poses[..., 0] = 1.0
    poses[:, 2, 4] = np.linspace(0.0, 0.05, T)
    tips = np.full((T, 2, 2, 3), np.nan, np.float32)
    tips[:, 1] = np.stack([[0.12, 0.02, 0.0], [0.12, -0.02, 0.0]])[None] + poses[:, 2, None, 4:]
    compile_s, ms = measure(rank_parts, parts, poses, tips, repeat=repeat)
    r = rank_parts(parts, poses, tips)
    out.append(
        record(
            NAME,
            {"stage": "rank", "frames": T, "parts": P, "points_per_part": N, "hands": 2},
            ms,
            compile_s,
            {"top_part_correct": int(r.part_order[0]) == 2},
        )
    )
    return out
