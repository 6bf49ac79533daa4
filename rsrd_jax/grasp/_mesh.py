"""Part meshes from point sets: alpha shape (Delaunay + circumradius filter), cavity filling,
manifold repair, Taubin smoothing and quadric-error decimation; convex-hull fallback.

Everything here is host-side numpy/scipy: it runs once per part and fixes the shapes that the
jitted grasp sampler sees.
"""

from __future__ import annotations

import heapq

import equinox as eqx
import numpy as np
import scipy.sparse
import scipy.sparse.csgraph
import scipy.spatial
import trimesh
from jaxtyping import Float, Int

# Face j of a tetrahedron is the face opposite vertex j.
_TET_FACES = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]])
_TET_EDGES = np.array([[0, 1], [0, 2], [0, 3], [1, 2], [1, 3], [2, 3]])


class MeshConfig(eqx.Module):
    """How a part's point set becomes a closed triangle mesh."""

    alpha: float | None = None
    """Alpha radius in metres (see `fill_cavities` for what it means). None sweeps alphas and
    takes the smallest one whose solid covers the points and whose volume has stopped jumping
    (RSRD uses a fixed 0.04 nerfstudio units)."""
    alpha_min_spacing: float = 1.5
    """Auto alpha: the sweep starts at this multiple of the median nearest-neighbour spacing and
    ends at the point set's diameter."""
    alpha_ratio: float = 1.25
    """Ratio between consecutive alphas in the sweep (and in the retries of a fixed alpha)."""
    plateau_tol: float = 0.1
    """Auto alpha: accept the first alpha whose solid volume is within this fraction of the
    volume at the next `plateau_steps` alphas (the surface has sealed)."""
    plateau_steps: int = 1
    """Auto alpha: how many larger alphas the plateau test looks ahead. One: a sealed surface
    jumps the volume by 2–40× in one step, while the fillets an alpha ball leaves in concave
    corners grow it by 5–15 % per step without end; looking two steps ahead, an open container
    (the studio toy_drawer's drawer: 61 → 68 → 71 → 77 → 88 cm³ from 5.7 mm on) never passed
    and was swept until its cavity was filled (195 cm³ at 53 mm; that drawer, with its earlier flush knob, was 69 cm³)."""
    max_alpha_retries: int = 4
    """Fixed alpha: how many times it may grow by `alpha_ratio` before the convex hull."""
    max_points: int = 1000
    """Larger point sets are first thinned on a voxel grid (one point per voxel) to at most this many points
    (speed: Delaunay and decimation dominate, and the mesh is decimated to `target_faces`
    anyway); 0 disables."""
    min_points: int = 20
    """Point sets smaller than this go straight to the convex hull."""
    min_component_fraction: float = 0.1
    """Solid components whose volume is below this fraction of the largest one are dropped
    (stray Gaussians)."""
    fill_cavities: bool = True
    """Alpha wrapping: the solid is everything an alpha ball cannot reach from outside through
    Delaunay triangles (so surface-only samples, as 3DGS centres are, give a solid rather than a
    hollow shell). False: the plain union of tetrahedra with circumradius < alpha."""
    min_coverage: float = 0.9
    """Fraction of the points that must be vertices of the solid for the alpha shape to be
    accepted (a leaky surface lets the flood in and leaves only fragments)."""
    smooth_iterations: int = 5
    """Taubin smoothing iterations (lambda 0.5, nu 0.53; shrinks far less than Laplacian)."""
    target_faces: int = 200
    """Quadric-error decimation target (RSRD decimates to 100 faces); 0 disables decimation."""


class PartMesh(eqx.Module):
    """A closed, outward-oriented triangle mesh of one part, in the part frame (metres)."""

    vertices: Float[np.ndarray, "v 3"]
    """Vertex positions, metres."""
    faces: Int[np.ndarray, "f 3"]
    """Triangles, counter-clockwise seen from outside (normals point outwards)."""
    method: str = eqx.field(static=True)
    """"alpha_shape" or "convex_hull"."""
    alpha: float = eqx.field(static=True)
    """Alpha radius used (metres); NaN for the convex hull."""
    watertight: bool = eqx.field(static=True)
    """Every edge is shared by exactly two consistently wound faces."""
    reason: str = eqx.field(static=True)
    """Why this method was chosen (e.g. why the alpha shape was rejected)."""

    def to_trimesh(self) -> trimesh.Trimesh:
        return trimesh.Trimesh(self.vertices, self.faces, process=False)

    @property
    def volume(self) -> float:
        return float(self.to_trimesh().volume)


def _circumradius(tets: Float[np.ndarray, "m 4 3"]) -> Float[np.ndarray, " m"]:
    """Circumradius of each tetrahedron (inf for flat ones)."""
    a = tets[:, 1:] - tets[:, :1]  # m 3 3, rows are edge vectors from vertex 0
    rhs = 0.5 * np.sum(a * a, axis=-1)
    det = np.linalg.det(a)
    ok = np.abs(det) > 1e-18 * np.max(np.abs(a), axis=(1, 2)) ** 3 + 1e-300
    a_safe = np.where(ok[:, None, None], a, np.eye(3)[None])
    centre = np.linalg.solve(a_safe, rhs[..., None])[..., 0]
    r = np.linalg.norm(centre, axis=-1)
    return np.where(ok, r, np.inf)


def _components(mask: np.ndarray, neighbors: np.ndarray) -> tuple[int, np.ndarray]:
    """Face-connected components of the tetrahedra selected by `mask`."""
    m = len(mask)
    src = np.repeat(np.arange(m), 4)
    dst = neighbors.reshape(-1)
    keep = (dst >= 0) & mask[src] & mask[np.maximum(dst, 0)]
    graph = scipy.sparse.coo_matrix((np.ones(keep.sum()), (src[keep], dst[keep])), shape=(m, m))
    return scipy.sparse.csgraph.connected_components(graph, directed=False)


def _boundary_faces(
    points: np.ndarray, simplices: np.ndarray, neighbors: np.ndarray, solid: np.ndarray
) -> np.ndarray:
    """Faces between solid and non-solid tetrahedra, wound outwards (away from the solid)."""
    nb = neighbors
    outside = (nb < 0) | ~solid[np.maximum(nb, 0)]
    tet_idx, face_idx = np.nonzero(solid[:, None] & outside)
    faces = simplices[tet_idx[:, None], _TET_FACES[face_idx]]
    opposite = simplices[tet_idx, face_idx]
    p0, p1, p2 = points[faces[:, 0]], points[faces[:, 1]], points[faces[:, 2]]
    normal = np.cross(p1 - p0, p2 - p0)
    flip = np.sum(normal * (p0 - points[opposite]), axis=-1) < 0
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return faces


def _nonmanifold_edge_tets(simplices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Indices of tetrahedra incident to an edge that more than two boundary faces share."""
    edges = np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    uniq, counts = np.unique(edges, axis=0, return_counts=True)
    bad = uniq[counts > 2]
    if len(bad) == 0:
        return np.zeros(0, dtype=np.int64)
    tet_edges = np.sort(simplices[:, _TET_EDGES], axis=-1).reshape(-1, 2)
    n = int(simplices.max()) + 1
    key_bad = bad[:, 0] * n + bad[:, 1]
    key_tet = tet_edges[:, 0] * n + tet_edges[:, 1]
    hit = np.isin(key_tet, key_bad)
    return np.unique(np.nonzero(hit)[0] // 6)


def _compact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    used = np.unique(faces)
    remap = -np.ones(len(vertices), dtype=np.int64)
    remap[used] = np.arange(len(used))
    return vertices[used], remap[faces]


def _triangle_circumradius(tri: Float[np.ndarray, "m 3 3"]) -> Float[np.ndarray, " m"]:
    a = np.linalg.norm(tri[:, 1] - tri[:, 2], axis=-1)
    b = np.linalg.norm(tri[:, 0] - tri[:, 2], axis=-1)
    c = np.linalg.norm(tri[:, 0] - tri[:, 1], axis=-1)
    area2 = np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=-1)
    return np.where(area2 > 0, a * b * c / np.maximum(2.0 * area2, 1e-300), np.inf)


class _Complex(eqx.Module):
    """Delaunay tetrahedralisation and the per-tetrahedron data the alpha sweep reuses."""

    points: np.ndarray
    simplices: np.ndarray
    neighbors: np.ndarray
    face_r: np.ndarray
    tet_r: np.ndarray
    volume: np.ndarray


def _complex(points: np.ndarray) -> _Complex:
    tri = scipy.spatial.Delaunay(points)
    simplices, nb = tri.simplices.astype(np.int64), tri.neighbors.astype(np.int64)
    m = len(simplices)
    tets = points[simplices]
    face_r = _triangle_circumradius(points[simplices[:, _TET_FACES]].reshape(-1, 3, 3)).reshape(m, 4)
    volume = np.abs(np.linalg.det(tets[:, 1:] - tets[:, :1])) / 6.0
    return _Complex(points, simplices, nb, face_r, _circumradius(tets), volume)


def _solid(cx: _Complex, alpha: float, config: MeshConfig) -> tuple[np.ndarray, float, float]:
    """Solid tetrahedra for one alpha. Returns (mask, fraction of points on it, volume).

    With `fill_cavities` the solid is the complement of the region a ball of radius alpha can
    reach from outside moving through the Delaunay complex: the flood crosses a triangle only
    when its circumradius is at least alpha (the ball fits through it), as in alpha wrapping.
    Unlike the plain "tetrahedra with circumradius < alpha" rule this is not fooled by flat
    sliver tetrahedra on a sampled surface (huge circumradius, tiny triangles), and closed
    surfaces come out solid rather than hollow.
    """
    m = len(cx.simplices)
    if config.fill_cavities:
        src = np.repeat(np.arange(m), 4)
        dst = cx.neighbors.reshape(-1)
        dst = np.where(dst < 0, m, dst)  # node m is the outside; hull faces connect to it
        keep = (cx.face_r >= alpha).reshape(-1)
        graph = scipy.sparse.coo_matrix(
            (np.ones(keep.sum()), (src[keep], dst[keep])), shape=(m + 1, m + 1)
        )
        _, labels = scipy.sparse.csgraph.connected_components(graph, directed=False)
        solid = labels[:m] != labels[m]
    else:
        solid = cx.tet_r < alpha
    if not solid.any():
        return solid, 0.0, 0.0
    ncomp, labels = _components(solid, cx.neighbors)
    comp_vol = np.bincount(labels[solid], weights=cx.volume[solid], minlength=ncomp)
    solid &= comp_vol[labels] >= config.min_component_fraction * comp_vol.max()
    on_solid = np.zeros(len(cx.points), dtype=bool)
    on_solid[cx.simplices[solid].reshape(-1)] = True
    coverage = float(on_solid.mean())
    return solid, coverage, float(cx.volume[solid].sum())


def _surface(cx: _Complex, solid: np.ndarray, alpha: float) -> tuple[np.ndarray, np.ndarray]:
    """Boundary of the solid, repaired where solid tetrahedra meet only along an edge
    (non-manifold edge): first fill the small empty tetrahedra around it (circumradius < 2
    alpha), else carve the solid ones; big fills would bridge concavities."""
    solid = solid.copy()
    faces = _boundary_faces(cx.points, cx.simplices, cx.neighbors, solid)
    for _ in range(10):
        bad = _nonmanifold_edge_tets(cx.simplices, faces)
        if len(bad) == 0:
            break
        fill = bad[~solid[bad] & (cx.tet_r[bad] < 2.0 * alpha)]
        if len(fill):
            solid[fill] = True
        else:
            solid[bad] = False
        faces = _boundary_faces(cx.points, cx.simplices, cx.neighbors, solid)
    return _compact(cx.points, faces)


def _alpha_candidates(points: np.ndarray, config: MeshConfig) -> np.ndarray:
    nn = scipy.spatial.cKDTree(points).query(points, k=2)[0][:, 1]
    lo = config.alpha_min_spacing * float(np.median(nn))
    hi = float(np.linalg.norm(points.max(0) - points.min(0)))
    n = int(np.ceil(np.log(max(hi / lo, 1.0 + 1e-9)) / np.log(config.alpha_ratio))) + 1
    return lo * config.alpha_ratio ** np.arange(max(n, 1))


def _is_watertight(vertices: np.ndarray, faces: np.ndarray) -> bool:
    if len(faces) < 4:
        return False
    m = trimesh.Trimesh(vertices, faces, process=False)
    return bool(m.is_watertight and m.is_winding_consistent and m.volume > 0)


def _qerr(q: list[float], x: float, y: float, z: float) -> float:
    a11, a12, a13, a14, a22, a23, a24, a33, a34, a44 = q
    return (
        a11 * x * x + a22 * y * y + a33 * z * z + a44
        + 2.0 * (a12 * x * y + a13 * x * z + a23 * y * z + a14 * x + a24 * y + a34 * z)
    )


def _cross(a: tuple, b: tuple) -> tuple[float, float, float]:
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


def _decimate(vertices: np.ndarray, faces: np.ndarray, target_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """Quadric-error edge collapse (Garland & Heckbert 1997) on a closed manifold mesh.

    Collapses keep the manifold property (link condition: the edge's endpoints share exactly
    two neighbours) and never flip a face normal. Plain Python floats: the per-collapse work is
    a handful of 3-vectors, where numpy's call overhead would dominate.
    """
    if target_faces <= 0 or len(faces) <= target_faces:
        return vertices, faces
    target_faces = max(target_faces, 4)
    V = [tuple(p) for p in vertices.astype(np.float64).tolist()]
    F = [list(f) for f in faces.tolist()]
    nv = len(V)
    p0, p1, p2 = (vertices[faces[:, j]].astype(np.float64) for j in range(3))
    cross = np.cross(p1 - p0, p2 - p0)
    area2 = np.linalg.norm(cross, axis=-1)
    n = cross / np.maximum(area2, 1e-30)[:, None]
    plane = np.concatenate([n, -np.sum(n * p0, axis=-1, keepdims=True)], axis=-1)
    K = 0.5 * area2[:, None, None] * plane[:, :, None] * plane[:, None, :]
    Qa = np.zeros((nv, 4, 4))
    for j in range(3):
        np.add.at(Qa, faces[:, j], K)
    iu = np.triu_indices(4)
    Q = Qa[:, iu[0], iu[1]].tolist()
    vf: list[set[int]] = [set() for _ in range(nv)]
    for fi, f in enumerate(F):
        for v in f:
            vf[v].add(fi)
    alive = [True] * len(F)
    dead = [False] * nv
    ver = [0] * nv

    def neighbours(u: int) -> set[int]:
        out = set()
        for fi in vf[u]:
            out.update(F[fi])
        out.discard(u)
        return out

    def best(u: int, v: int) -> tuple[float, tuple]:
        q = [a + b for a, b in zip(Q[u], Q[v])]
        a11, a12, a13, a14, a22, a23, a24, a33, a34, _ = q
        pu, pv = V[u], V[v]
        mid = ((pu[0] + pv[0]) * 0.5, (pu[1] + pv[1]) * 0.5, (pu[2] + pv[2]) * 0.5)
        cands = [pu, pv, mid]
        det = a11 * (a22 * a33 - a23 * a23) - a12 * (a12 * a33 - a23 * a13) + a13 * (a12 * a23 - a22 * a13)
        scale = max(abs(a11), abs(a22), abs(a33), 1e-300)
        if abs(det) > 1e-10 * scale**3:
            # Cramer's rule for A x = -b.
            b1, b2, b3 = -a14, -a24, -a34
            x = (b1 * (a22 * a33 - a23 * a23) - a12 * (b2 * a33 - a23 * b3) + a13 * (b2 * a23 - a22 * b3)) / det
            y = (a11 * (b2 * a33 - a23 * b3) - b1 * (a12 * a33 - a23 * a13) + a13 * (a12 * b3 - b2 * a13)) / det
            z = (a11 * (a22 * b3 - b2 * a23) - a12 * (a12 * b3 - b2 * a13) + b1 * (a12 * a23 - a22 * a13)) / det
            edge = sum((pu[i] - pv[i]) ** 2 for i in range(3)) ** 0.5
            dist = ((x - mid[0]) ** 2 + (y - mid[1]) ** 2 + (z - mid[2]) ** 2) ** 0.5
            # The optimum keeps sharp edges and corners; accept it only near the edge, since on
            # flat regions it is ill-conditioned and can slide off the sampled surface.
            if dist < edge:
                cands.append((x, y, z))
        errs = [_qerr(q, *c) for c in cands]
        i = min(range(len(cands)), key=errs.__getitem__)
        return errs[i], cands[i]

    heap: list = []

    def push(u: int, v: int) -> None:
        c, x = best(u, v)
        heapq.heappush(heap, (c, u, v, ver[u], ver[v], x))

    edges = np.unique(np.sort(faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1), axis=0)
    for u, v in edges.tolist():
        push(u, v)
    count = len(F)
    while count > target_faces and heap:
        _, u, v, vu, vv, x = heapq.heappop(heap)
        if dead[u] or dead[v] or ver[u] != vu or ver[v] != vv:
            continue
        shared = vf[u] & vf[v]
        if len(shared) != 2 or len(neighbours(u) & neighbours(v)) != 2:
            continue
        ok = True
        for fi in (vf[u] | vf[v]) - shared:
            a, b, c = (V[w] for w in F[fi])
            a2, b2, c2 = (x if w in (u, v) else V[w] for w in F[fi])
            n_old = _cross((b[0] - a[0], b[1] - a[1], b[2] - a[2]), (c[0] - a[0], c[1] - a[1], c[2] - a[2]))
            n_new = _cross(
                (b2[0] - a2[0], b2[1] - a2[1], b2[2] - a2[2]), (c2[0] - a2[0], c2[1] - a2[1], c2[2] - a2[2])
            )
            dot = n_old[0] * n_new[0] + n_old[1] * n_new[1] + n_old[2] * n_new[2]
            if dot <= 1e-3 * (n_old[0] ** 2 + n_old[1] ** 2 + n_old[2] ** 2):
                ok = False
                break
        if not ok:
            continue
        for fi in shared:
            alive[fi] = False
            for w in F[fi]:
                vf[w].discard(fi)
        for fi in vf[v]:
            F[fi] = [u if w == v else w for w in F[fi]]
            vf[u].add(fi)
        vf[v] = set()
        V[u] = x
        Q[u] = [a + b for a, b in zip(Q[u], Q[v])]
        dead[v] = True
        ver[u] += 1
        ver[v] += 1
        count -= 2
        for w in neighbours(u):
            push(min(u, w), max(u, w))
    keep = np.array([f for f, a in zip(F, alive) if a], dtype=np.int64)
    return _compact(np.array(V), keep)


def _voxel_downsample(points: np.ndarray, max_points: int) -> np.ndarray:
    """One point per occupied voxel (the one nearest the voxel's mean: a real sample, so
    surface samples stay on the surface), with the voxel grown until at most max_points voxels
    are occupied."""
    if max_points <= 0 or len(points) <= max_points:
        return points
    lo = points.min(0)
    extent = float(np.max(points.max(0) - lo))
    voxel = extent / max_points ** (1.0 / 3.0) / 4.0
    while True:
        idx = np.floor((points - lo) / voxel).astype(np.int64)
        _, inverse, counts = np.unique(idx, axis=0, return_inverse=True, return_counts=True)
        if len(counts) <= max_points:
            break
        voxel *= 1.1
    inverse = inverse.reshape(-1)
    sums = np.zeros((len(counts), 3))
    np.add.at(sums, inverse, points)
    dist = np.linalg.norm(points - (sums / counts[:, None])[inverse], axis=-1)
    order = np.lexsort((dist, inverse))
    first = np.ones(len(order), dtype=bool)
    first[1:] = inverse[order][1:] != inverse[order][:-1]
    return points[order[first]]


def _convex_hull(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    try:
        hull = scipy.spatial.ConvexHull(points)
    except scipy.spatial.QhullError:
        # Flat or collinear set: joggle so that Qhull returns a (thin) closed hull.
        hull = scipy.spatial.ConvexHull(points, qhull_options="QJ")
    faces = hull.simplices.astype(np.int64)
    centre = points[np.unique(faces)].mean(axis=0)
    p0, p1, p2 = points[faces[:, 0]], points[faces[:, 1]], points[faces[:, 2]]
    flip = np.sum(np.cross(p1 - p0, p2 - p0) * (p0 - centre), axis=-1) < 0
    faces[flip] = faces[flip][:, [0, 2, 1]]
    return _compact(points, faces)


def _finish(vertices: np.ndarray, faces: np.ndarray, config: MeshConfig) -> tuple[np.ndarray, np.ndarray]:
    if config.smooth_iterations > 0:
        m = trimesh.Trimesh(vertices, faces, process=False)
        trimesh.smoothing.filter_taubin(m, lamb=0.5, nu=0.53, iterations=config.smooth_iterations)
        vertices = np.asarray(m.vertices)
    return _decimate(vertices, faces, config.target_faces)


def build_part_mesh(
    points: Float[np.ndarray, "n 3"], config: MeshConfig = MeshConfig()
) -> PartMesh:
    """Closed mesh of a part from its point set (Gaussian centres in the part frame).

    Alpha shape by alpha wrapping of the Delaunay complex (see `MeshConfig.fill_cavities`): its
    boundary faces are wound away from the solid, so normals point outwards by construction.
    Alpha is swept (or grown from `config.alpha`) until the solid covers the points, its volume
    has settled and its surface is watertight. Then Taubin smoothing and quadric decimation.
    Tiny sets, degenerate sets and persistent failures fall back to the convex hull, with the
    reason in `PartMesh.reason`.

    Args:
        points: N×3 positions in metres (N ≥ 4, finite).
        config: meshing options.

    Returns:
        PartMesh in the same frame as `points`.
    """
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points: expected shape (n, 3), got {pts.shape}")
    if not np.all(np.isfinite(pts)):
        raise ValueError("points: contains NaN or inf")
    pts = np.unique(pts, axis=0)
    if len(pts) < 4:
        raise ValueError(f"points: need at least 4 distinct points for a mesh, got {len(pts)}")

    pts = _voxel_downsample(pts, config.max_points)
    reason = ""
    if len(pts) < config.min_points:
        reason = f"{len(pts)} points < min_points={config.min_points}"
    else:
        try:
            cx = _complex(pts)
        except scipy.spatial.QhullError:
            cx = None
            reason = "Delaunay failed (degenerate, e.g. coplanar points)"
        if cx is not None:
            if config.alpha is not None:
                alphas = config.alpha * config.alpha_ratio ** np.arange(config.max_alpha_retries + 1)
            else:
                alphas = _alpha_candidates(pts, config)
            cache: dict[int, tuple[np.ndarray, float, float]] = {}

            def sweep(i: int) -> tuple[np.ndarray, float, float]:
                if i not in cache:
                    cache[i] = _solid(cx, float(alphas[i]), config)
                return cache[i]

            reason = f"no watertight alpha shape covering {config.min_coverage:.0%} of the points"
            for k in range(len(alphas)):
                solid, coverage, vol = sweep(k)
                if coverage < config.min_coverage or vol <= 0:
                    continue
                # Plateau test (auto alpha only): a leaky surface lets the flood in and the
                # volume jumps once alpha seals it; accept alpha once the volume has settled.
                later = range(k + 1, min(k + 1 + config.plateau_steps, len(alphas)))
                if config.alpha is None and any(sweep(i)[2] * (1 - config.plateau_tol) > vol for i in later):
                    continue
                v, f = _surface(cx, solid, float(alphas[k]))
                if not _is_watertight(v, f):
                    continue
                alpha = float(alphas[k])
                v, f = _finish(v, f, config)
                msg = f"alpha shape (alpha {alpha * 1e3:.2f} mm, {coverage:.0%} of points on the solid)"
                return PartMesh(v, f, "alpha_shape", alpha, _is_watertight(v, f), msg)
    v, f = _convex_hull(pts)
    v, f = _decimate(v, f, config.target_faces)
    return PartMesh(v, f, "convex_hull", float("nan"), _is_watertight(v, f), reason)
