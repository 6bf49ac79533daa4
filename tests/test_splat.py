"""Tile rasterizer against the dense brute-force reference, finite differences and edge cases."""

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import jaxlie
import numpy as np
import pytest

from rsrd_jax.geometry import Camera, Intrinsics
from rsrd_jax.splat import (
    Gaussians,
    RenderConfig,
    apply_part_poses,
    blend_weights,
    bins_for,
    choose_config,
    project_gaussians,
    render,
    rest_part_poses,
)
from rsrd_jax.splat import _raster
from rsrd_jax.splat._project import quat_to_rotmat
from rsrd_jax.splat._reference import render_reference

W, H = 64, 48
# One generous config shared by most tests (one compilation per scene size).
CFG = RenderConfig(tile_size=4, chunk_size=16, capacity=160, max_chunks=1024, max_pairs=16384)
IMAGE_KEYS = ("rgb", "features", "depth_accum", "alpha")
N = 200  # every float32 scene is padded to N Gaussians so that `render` compiles once
_reference = jax.jit(render_reference)


def _pad(g: Gaussians) -> Gaussians:
    return g.padded(N)


@eqx.filter_jit
def _loss_and_grad(g, T, cot, bg):
    """Σ cot·outputs of the tiled render and its gradient wrt (Gaussians, camera pose)."""

    def loss(args):
        gg, TT = args
        o = render(gg, _camera(TT), CFG, bg)
        return sum(jnp.sum(getattr(o, k) * c) for k, c in cot.items())

    return eqx.filter_value_and_grad(loss)((g, T))


def _intrinsics(dtype=jnp.float32) -> Intrinsics:
    f = lambda x: jnp.asarray(x, dtype)  # noqa: E731
    return Intrinsics(f(50.0), f(52.0), f(31.0), f(25.0), W, H)


def _scene(seed: int, n: int = N, f: int = 5, dtype=np.float32, parts: int = 1) -> Gaussians:
    rng = np.random.default_rng(seed)
    z = rng.uniform(2.0, 4.0, n)
    means = np.stack([rng.uniform(-0.7, 0.7, n) * z, rng.uniform(-0.6, 0.6, n) * z, z], -1)
    arrays = dict(
        means=means,
        quats=rng.normal(size=(n, 4)),
        log_scales=np.log(rng.uniform(0.02, 0.2, (n, 3))),
        opacity_logits=rng.normal(0.5, 1.5, n),
        colours=rng.uniform(0, 1, (n, 3)),
        features=rng.normal(size=(n, f)),
    )
    arrays = {k: jnp.asarray(v, dtype) for k, v in arrays.items()}
    return Gaussians(**arrays, part_ids=jnp.asarray(rng.integers(0, parts, n), jnp.int32))


def _camera(T=None, dtype=jnp.float32) -> Camera:
    T = jaxlie.SE3(jnp.asarray([1.0, 0, 0, 0, 0, 0, 0], dtype)) if T is None else T
    return Camera(_intrinsics(dtype), T)


def _random_pose(rng, scale=0.05) -> jaxlie.SE3:
    return jaxlie.SE3.exp(jnp.asarray(rng.normal(size=6) * scale, jnp.float32))


def _assert_matches_reference(out, ref, atol=2e-5):
    for k in IMAGE_KEYS:
        np.testing.assert_allclose(np.asarray(getattr(out, k)), np.asarray(ref[k]), atol=atol, err_msg=k)
    a = np.asarray(ref["alpha"])
    mask = a > 0.05
    np.testing.assert_allclose(np.asarray(out.depth)[mask], np.asarray(ref["depth"])[mask], rtol=1e-4)


@pytest.mark.parametrize("seed", [0, 1])
def test_forward_matches_dense_reference(seed):
    g = _scene(seed)
    rng = np.random.default_rng(seed)
    cam = _camera(_random_pose(rng))
    bg = jnp.asarray([0.1, 0.5, 0.9])
    out = render(g, cam, dataclasses.replace(CFG, stats=True), bg)
    ref = _reference(g, cam, bg)
    _assert_matches_reference(out, ref)
    assert int(out.pairs_overflow) == 0 and int(out.chunks_overflow) == 0
    assert not bool(jnp.any(out.tile_truncated)) and int(jnp.max(out.tile_overflow)) == 0
    # Same contributor counts per pixel: the tiles dropped no pair with α ≥ 1/255.
    np.testing.assert_array_equal(np.asarray(out.n_contrib), np.asarray(ref["n_contrib"]))
    assert float(jnp.mean(out.alpha)) > 0.3  # the scene is not trivially empty


def _cotangents(rng):
    shapes = {"rgb": (H, W, 3), "features": (H, W, 5), "depth_accum": (H, W), "alpha": (H, W)}
    cot = {k: jnp.asarray(rng.normal(size=s), jnp.float32) for k, s in shapes.items()}
    cot["depth"] = jnp.asarray(rng.normal(size=(H, W)) * 0.1, jnp.float32)
    return cot


@eqx.filter_jit
def _reference_grad(g, T, cot, bg):
    def loss(args):
        o = render_reference(args[0], _camera(args[1]), bg)
        return sum(jnp.sum(o[k] * c) for k, c in cot.items())

    return eqx.filter_grad(loss)((g, T))


def test_vjp_matches_dense_reference():
    g = _scene(3)
    rng = np.random.default_rng(3)
    T = _random_pose(rng)
    bg = jnp.asarray([0.2, 0.3, 0.4])
    cot = _cotangents(rng)
    _, (gt, Tt) = _loss_and_grad(g, T, cot, bg)
    gr, Tr = _reference_grad(g, T, cot, bg)
    for name in ("means", "quats", "log_scales", "opacity_logits", "colours", "features"):
        a, b = np.asarray(getattr(gt, name)), np.asarray(getattr(gr, name))
        scale = np.max(np.abs(b))
        assert scale > 0, name
        np.testing.assert_allclose(a, b, atol=2e-5 * scale + 1e-5, err_msg=name)
    np.testing.assert_allclose(np.asarray(Tt.wxyz_xyz), np.asarray(Tr.wxyz_xyz), rtol=1e-4, atol=1e-3)


def test_gradients_match_finite_differences_x64():
    """Means, quaternions and part poses (tangent-space perturbations), in float64."""
    with jax.enable_x64(True):
        g = _scene(5, n=60, f=2, dtype=np.float64, parts=3)
        rng = np.random.default_rng(5)
        cam = _camera(dtype=jnp.float64)
        cfg = RenderConfig(tile_size=8, chunk_size=16, capacity=64, max_chunks=128, max_pairs=2048)
        first = render(g, cam, cfg)
        assert not bool(jnp.any(first.tile_truncated))
        cot = {k: jnp.asarray(rng.normal(size=getattr(first, k).shape)) for k in IMAGE_KEYS}
        centroids = jnp.asarray(rng.normal(size=(3, 3)) * 0.3 + [0, 0, 3])
        rest = rest_part_poses(centroids)

        @jax.jit
        def loss(x):
            means, quats, xi = x
            gg = eqx.tree_at(lambda t: (t.means, t.quats), g, (means, quats))
            o = render(apply_part_poses(gg, rest @ jaxlie.SE3.exp(xi), centroids), cam, cfg)
            return sum(jnp.sum(getattr(o, k) * c) for k, c in cot.items())

        x = (g.means, g.quats, jnp.zeros((3, 6)))
        grad = jax.jit(jax.grad(loss))(x)
        eps = 1e-6
        for i in range(3):  # one direction per argument: means, quaternions, part poses
            d = [jnp.zeros_like(a) for a in x]
            d[i] = jnp.asarray(rng.normal(size=x[i].shape))
            analytic = float(jnp.vdot(grad[i], d[i]))
            plus = tuple(a + eps * b for a, b in zip(x, d))
            minus = tuple(a - eps * b for a, b in zip(x, d))
            numeric = float(loss(plus) - loss(minus)) / (2 * eps)
            assert abs(analytic) > 1e-3
            np.testing.assert_allclose(analytic, numeric, rtol=1e-5, err_msg=str(i))


def test_apply_part_poses_moves_means_and_covariances():
    g = _scene(7, n=50, parts=2)
    rng = np.random.default_rng(7)
    centroids = jnp.asarray(rng.normal(size=(2, 3)), jnp.float32)
    rest = rest_part_poses(centroids)
    same = apply_part_poses(g, rest, centroids)
    np.testing.assert_allclose(np.asarray(same.means), np.asarray(g.means), atol=1e-5)
    np.testing.assert_allclose(np.asarray(same.quats), np.asarray(g.quats), atol=1e-6)
    delta = jaxlie.SE3.exp(jnp.asarray(rng.normal(size=(2, 6)), jnp.float32))
    moved = apply_part_poses(g, rest @ delta, centroids)
    ids = np.asarray(g.part_ids)
    R = np.asarray(delta.rotation().as_matrix())[ids]
    t = np.asarray(delta.translation())[ids]
    c = np.asarray(centroids)[ids]
    expected = np.einsum("nij,nj->ni", R, np.asarray(g.means) - c) + t + c
    np.testing.assert_allclose(np.asarray(moved.means), expected, atol=1e-5)

    def cov(q, s):
        Rq = np.asarray(quat_to_rotmat(q / jnp.linalg.norm(q, axis=-1, keepdims=True)))
        return np.einsum("nij,nj,nkj->nik", Rq, s**2, Rq)

    s = np.asarray(g.scales())
    np.testing.assert_allclose(
        cov(moved.quats, s), np.einsum("nij,njk,nlk->nil", R, cov(g.quats, s), R), atol=1e-6
    )


def _edge_scene() -> Gaussians:
    base = _scene(11, n=120)
    rng = np.random.default_rng(11)
    n_extra = 40
    means, log_scales = [], []
    for i in range(n_extra):
        kind = i % 4
        if kind == 0:  # behind the camera or inside the near plane
            means.append([rng.uniform(-1, 1), rng.uniform(-1, 1), rng.choice([-2.0, 0.005])])
            log_scales.append(np.log([0.1, 0.1, 0.1]))
        elif kind == 1:  # mean exactly on a tile border (pixel 8, 16, ...)
            z = 3.0
            u, v = 8.0 * rng.integers(1, 8), 8.0 * rng.integers(1, 6)
            means.append([(u - 31.0) * z / 50.0, (v - 25.0) * z / 52.0, z])
            log_scales.append(np.log(rng.uniform(0.01, 0.05, 3)))
        elif kind == 2:  # centre outside the image, footprint partly inside or not at all
            z = 3.0
            u = rng.choice([-3.0, W + 3.0, -40.0])
            means.append([(u - 31.0) * z / 50.0, rng.uniform(-0.5, 0.5) * z, z])
            log_scales.append(np.log(rng.uniform(0.05, 0.15, 3)))
        else:  # degenerate: flat, or a point
            means.append([rng.uniform(-1, 1), rng.uniform(-0.8, 0.8), 2.5])
            log_scales.append(np.log([0.1, 1e-7, 0.1]) if i % 8 == 3 else np.log([1e-8, 1e-8, 1e-8]))
    extra = Gaussians(
        means=jnp.asarray(means, jnp.float32),
        quats=jnp.asarray(rng.normal(size=(n_extra, 4)), jnp.float32),
        log_scales=jnp.asarray(log_scales, jnp.float32),
        opacity_logits=jnp.full((n_extra,), 3.0),
        colours=jnp.asarray(rng.uniform(0, 1, (n_extra, 3)), jnp.float32),
        features=jnp.asarray(rng.normal(size=(n_extra, 5)), jnp.float32),
        part_ids=jnp.zeros(n_extra, jnp.int32),
    )
    return _pad(jax.tree.map(lambda a, b: jnp.concatenate([a, b]), base, extra))


def test_edge_cases_match_reference():
    """Behind the camera, on tile borders, outside the image, degenerate scales."""
    g = _edge_scene()
    cam = _camera()
    bg = jnp.zeros(3)
    out = render(g, cam, CFG, bg)
    _assert_matches_reference(out, _reference(g, cam, bg))
    assert not bool(jnp.any(out.tile_truncated))
    proj = project_gaussians(g, cam)
    behind = np.asarray(g.means[:160, 2]) < 0.01  # (the rest is padding)
    assert behind.sum() == 10 and not np.any(np.asarray(proj.visible)[:160][behind])
    _, grads = _loss_and_grad(g, cam.T_cam_world, _cotangents(np.random.default_rng(0)), bg)
    for leaf in jax.tree.leaves(eqx.filter(grads, eqx.is_inexact_array)):
        assert bool(jnp.all(jnp.isfinite(leaf)))


def test_zero_opacity_padding_changes_nothing():
    g = _scene(13, n=150)
    padded = _pad(g)
    cam = _camera()
    bg = jnp.zeros(3)
    _assert_matches_reference(render(padded, cam, CFG, bg), _reference(g, cam, bg))
    _, (grads, _) = _loss_and_grad(padded, cam.T_cam_world, _cotangents(np.random.default_rng(1)), bg)
    for leaf in (grads.means, grads.quats, grads.log_scales, grads.opacity_logits, grads.colours):
        assert not bool(jnp.any(leaf[150:] != 0))
        assert bool(jnp.any(leaf[:150] != 0))


def test_overflow_is_reported_and_saturated_overflow_is_exact():
    rng = np.random.default_rng(17)
    n = 64
    # A stack of large Gaussians all covering the same tiles; opaque ones saturate the centre.
    z = np.linspace(2.0, 3.0, n)
    means = np.stack([np.zeros(n), np.zeros(n), z], -1) + rng.normal(size=(n, 3)) * 0.01
    g = _pad(
        Gaussians(
            means=jnp.asarray(means, jnp.float32),
            quats=jnp.tile(jnp.asarray([[1.0, 0, 0, 0]]), (n, 1)),
            log_scales=jnp.full((n, 3), np.log(0.3), jnp.float32),
            opacity_logits=jnp.full((n,), 8.0),  # α capped at MAX_ALPHA near the centre
            colours=jnp.asarray(rng.uniform(0, 1, (n, 3)), jnp.float32),
            features=jnp.zeros((n, 5), jnp.float32),
            part_ids=jnp.zeros(n, jnp.int32),
        )
    )
    cam = _camera()
    small = RenderConfig(tile_size=8, chunk_size=8, capacity=16, max_chunks=256, max_pairs=4096)
    out = render(g, cam, small)
    over = np.asarray(out.tile_overflow) > 0
    trunc = np.asarray(out.tile_truncated)
    assert np.all(trunc <= over)  # only overflowing tiles can be truncated
    ref = _reference(g, cam, None)
    err = np.max(np.abs(np.asarray(out.rgb) - np.asarray(ref["rgb"])), axis=-1)
    per_tile = err.reshape(6, 8, 8, 8).max(axis=(1, 3))
    assert np.all(per_tile[~trunc] < 2e-5)  # tiles not flagged are exact ...
    assert np.any(over & ~trunc)  # ... including saturated tiles that overflowed
    assert np.any(per_tile[trunc] > 1e-3)  # and flagged tiles really are wrong
    # Soft Gaussians never saturate: every overflow is then a truncation.
    soft = eqx.tree_at(lambda gg: gg.opacity_logits, g, g.opacity_logits.at[:n].set(-3.0))
    out2 = render(soft, cam, small)
    assert np.array_equal(np.asarray(out2.tile_truncated), np.asarray(out2.tile_overflow) > 0)
    assert bool(jnp.any(out2.tile_truncated))
    # Pair and chunk budgets are reported too.
    tiny = RenderConfig(tile_size=8, chunk_size=8, capacity=16, max_chunks=4, max_pairs=64)
    out3 = render(soft, cam, tiny)
    assert int(out3.pairs_overflow) > 0 and int(out3.chunks_overflow) > 0


def test_choose_config_is_exact():
    g = _scene(19)
    cams = [_camera(), _camera(jaxlie.SE3.exp(jnp.asarray([0.1, 0, 0, 0, 0.05, 0], jnp.float32)))]
    cfg = choose_config(g, cams, tile_size=8, chunk_size=16, headroom=1.0)  # non-default tiles
    assert cfg.tile_size == 8
    for cam in cams:
        out = render(g, cam, cfg)
        assert not bool(jnp.any(out.tile_truncated))
        _assert_matches_reference(out, _reference(g, cam, None))
    # separate margins for the list capacity and the pair budget; the chunk budget keeps `headroom`
    wide = choose_config(g, cams, tile_size=8, chunk_size=16, headroom=1.0, capacity_headroom=2.0, pairs_headroom=3.0)
    assert cfg.capacity < wide.capacity <= 2 * cfg.capacity and 2 * cfg.max_pairs <= wide.max_pairs <= 3 * cfg.max_pairs + 1024
    assert wide.max_chunks >= cfg.max_chunks  # a larger capacity keeps more entries of the fullest tiles
    with pytest.raises(ValueError, match="capacity_headroom"):
        choose_config(g, cams, capacity_headroom=0.5)


def test_vmap_over_cameras_and_no_retrace():
    g = _scene(23)
    rng = np.random.default_rng(23)
    Ts = jaxlie.SE3.exp(jnp.asarray(rng.normal(size=(3, 6)) * 0.05, jnp.float32))
    batched = jax.vmap(lambda T: render(g, _camera(T), CFG))(Ts)
    for i in range(3):
        single = render(g, _camera(jaxlie.SE3(Ts.wxyz_xyz[i])), CFG)
        for k in IMAGE_KEYS:
            np.testing.assert_allclose(
                np.asarray(getattr(batched, k)[i]), np.asarray(getattr(single, k)), atol=1e-5
            )
    # Same shapes, new values: no new trace of `render`.
    before = _raster._trace_count
    for i in range(3):
        g2 = eqx.tree_at(lambda gg: gg.means, g, g.means + 0.01 * i)
        render(g2, _camera(jaxlie.SE3(Ts.wxyz_xyz[i])), CFG).rgb.block_until_ready()
    assert _raster._trace_count == before


def test_render_on_given_bins():
    """`render(bins=)`: on the lists of the same pose it is the binned render, gradient included;
    on the lists of a pose a fraction of a pixel away it renders the moved Gaussians (its mean
    error against the dense reference there a small fraction of the move's change); lists that
    do not fit the render's budgets or tile grid are refused."""
    g = _scene(31)
    cam = _camera()
    bins = bins_for(g, cam, CFG)
    fresh, given = render(g, cam, CFG), render(g, cam, CFG, bins=bins)
    for k in IMAGE_KEYS + ("depth", "tile_counts", "tile_truncated"):
        np.testing.assert_array_equal(np.asarray(getattr(given, k)), np.asarray(getattr(fresh, k)), err_msg=k)
    grad = lambda b: jax.grad(lambda m: jnp.sum(render(eqx.tree_at(lambda gg: gg.means, g, m), cam, CFG, bins=b).features))(g.means)  # noqa: E731
    np.testing.assert_allclose(np.asarray(grad(bins)), np.asarray(grad(None)), rtol=1e-6, atol=1e-7)

    # a small lateral move (0.3 px at z = 3) and a slight turn
    T = jaxlie.SE3.exp(jnp.asarray([0.018, -0.012, 0.0, 0.0, 0.004, 0.002], jnp.float32))
    moved = eqx.tree_at(lambda gg: (gg.means, gg.quats), g, (jax.vmap(T.apply)(g.means), jax.vmap(lambda q: (T.rotation() @ jaxlie.SO3(q / jnp.linalg.norm(q))).wxyz)(g.quats)))
    stale = render(moved, cam, CFG, bins=bins)
    ref_moved, ref_still = _reference(moved, cam), _reference(g, cam)
    for k in ("rgb", "features", "alpha"):
        # mean absolute differences (measured: error ≈ 0.6 % of the change; the largest pixel
        # errors are where the turn reorders overlapping Gaussians)
        err = np.abs(np.asarray(getattr(stale, k)) - np.asarray(ref_moved[k])).mean()
        change = np.abs(np.asarray(ref_moved[k]) - np.asarray(ref_still[k])).mean()
        assert err < 0.03 * change, (k, err, change)
    with pytest.raises(ValueError, match="do not fit"):
        render(g, cam, dataclasses.replace(CFG, max_chunks=CFG.max_chunks // 2), bins=bins)


@pytest.mark.slow
def test_vmap_over_part_poses_gradient():
    g = _scene(29, parts=2)
    rng = np.random.default_rng(29)
    centroids = jnp.asarray([[0.0, 0.0, 3.0], [0.5, 0.0, 3.0]], jnp.float32)
    rest = rest_part_poses(centroids)
    xis = jnp.asarray(rng.normal(size=(3, 2, 6)) * 0.02, jnp.float32)
    cam = _camera()

    def loss(xi):
        posed = apply_part_poses(g, rest @ jaxlie.SE3.exp(xi), centroids)
        return jnp.sum(render(posed, cam, CFG).features ** 2)

    batched = jax.jit(jax.vmap(jax.grad(loss)))(xis)
    single = jax.jit(jax.grad(loss))
    for i in range(3):
        np.testing.assert_allclose(np.asarray(batched[i]), np.asarray(single(xis[i])), rtol=1e-4, atol=1e-3)
    assert bool(jnp.all(jnp.isfinite(batched))) and float(jnp.max(jnp.abs(batched))) > 0


def test_materialise_stays_a_conditional_under_vmap():
    """`materialise` keeps XLA from fusing stored values into their consumers by passing them
    through a `cond`. Under vmap a data-derived predicate would be batched and the `cond` would
    become a `select` (measured: the vmapped render gradient then cost 9× a single one); its
    batching rule keeps one `cond` for the whole batch, as many as in the unbatched gradient."""
    from rsrd_jax.splat._composite import materialise

    g = _scene(29, parts=2)
    centroids = jnp.asarray([[0.0, 0.0, 3.0], [0.5, 0.0, 3.0]], jnp.float32)
    rest = rest_part_poses(centroids)
    cam = _camera()

    def loss(xi):
        posed = apply_part_poses(g, rest @ jaxlie.SE3.exp(xi), centroids)
        return jnp.sum(render(posed, cam, CFG).features ** 2)

    def conds(jaxpr) -> int:
        return str(jaxpr).count(" cond[")

    xis = jnp.zeros((3, 2, 6), jnp.float32)
    single = conds(jax.make_jaxpr(jax.grad(loss))(xis[0]))
    batched = conds(jax.make_jaxpr(jax.vmap(jax.grad(loss)))(xis))
    if jax.default_backend() == "cpu":
        assert single >= 2
    assert batched == single
    x = jnp.arange(12.0).reshape(3, 4)
    np.testing.assert_array_equal(np.asarray(jax.vmap(materialise)(x)), np.asarray(x))
    assert conds(jax.make_jaxpr(jax.vmap(materialise))(x)) == (1 if jax.default_backend() == "cpu" else 0)


def test_choose_config_host_lists_cover_device_lists():
    """`choose_config` sizes budgets from numpy lists: they must hold every pair the device
    binning keeps (a superset: the host ellipse test is slightly looser), with the same total."""
    g = _scene(31)
    cam = _camera(_random_pose(np.random.default_rng(31)))
    proj = project_gaussians(g, cam)
    TX, TY = _raster._grid(cam, CFG.tile_size)
    gid, bounds, total = _raster._host_pairs(proj, TX, TY, CFG.tile_size)
    bins = _raster.bin_gaussians(proj, cam, CFG)
    assert total == int(bins.total_pairs) and int(bins.total_chunks) <= CFG.max_chunks
    ids, tiles = np.asarray(bins.ids), np.asarray(bins.layout.tile)
    used = np.asarray(bins.layout.count) > 0
    for t in range(TX * TY):
        device = ids[used & (tiles == t)].reshape(-1)
        device = device[device < N]
        host = gid[bounds[t] : bounds[t + 1]]
        assert set(device.tolist()) <= set(host.tolist()), t
        # near to far in both
        order = {k: i for i, k in enumerate(host.tolist())}
        assert [order[k] for k in device.tolist()] == sorted(order[k] for k in device.tolist()), t
    assert int(np.sum(np.diff(bounds))) >= int(np.sum(np.asarray(bins.counts))) > 0


def test_composite_rows_matches_composite():
    """The table + row-ids compositor used by `render` (depth and alpha apart from the channel
    GEMM) and the public `composite` (them as two more channels) agree in value and VJP."""
    from rsrd_jax.splat import _composite

    g = _scene(4)
    cam = _camera()
    ts = CFG.tile_size
    TX, TY = _raster._grid(cam, ts)
    kc = CFG.capacity // CFG.chunk_size

    @jax.jit
    def both(g, ct, ct_aux):
        proj = project_gaussians(g, cam)
        bins = _raster.bin_gaussians(proj, cam, CFG)
        params, table, depth = _raster._tile_inputs(g, proj, bins, cam, ts)

        def rows(p, t, d):
            out, aux, _ = _composite.composite_rows(p, t, d, bins.ids, bins.layout, TX * TY, ts, kc)
            return out, aux

        def plain(p, t, d):  # depth and alpha as two more channels
            chans = jnp.concatenate([t, d[:, None], jnp.ones_like(d)[:, None]], -1)[bins.ids]
            out = _composite.composite(p, chans, bins.layout, TX * TY, ts, kc)[0]
            return out[..., :-2], out[..., -2:]

        o1, vjp1 = jax.vjp(rows, params, table, depth)
        o2, vjp2 = jax.vjp(plain, params, table, depth)
        return o1, o2, vjp1((ct, ct_aux)), vjp2((ct, ct_aux))

    k1, k2 = jax.random.split(jax.random.PRNGKey(0))
    ct = jax.random.normal(k1, (TX * TY, ts * ts, 3 + 5))
    ct_aux = jax.random.normal(k2, (TX * TY, ts * ts, 2))
    o1, o2, d1, d2 = both(g, ct, ct_aux)
    for a, b in zip(o1, o2):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-5)
    for a, b in zip(d1, d2):
        np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-5 * float(np.abs(b).max()))


@pytest.mark.parametrize("reverse", [False, True])
def test_chunk_carry_sums_each_tiles_earlier_or_later_chunks(rng, reverse):
    """`_chunk_carry` against a brute-force sum over the chunks of the same tile before (after)
    each chunk: 7 tiles with 0–9 chunks (one at the full 9), chunks laid out tile by tile as
    binning leaves them, unused chunks at the end (carry 0)."""
    from rsrd_jax.splat._composite import ChunkLayout, _chunk_carry

    kc, nc, P = 9, 40, 5
    counts = rng.integers(0, 6, 7)
    counts[2] = kc
    tile = [t for t, c in enumerate(counts) for _ in range(c)]
    index = [i for c in counts for i in range(c)]
    n = len(tile)
    pad = nc - n
    tile, index, count = tile + [0] * pad, index + [0] * pad, [counts[t] for t in tile[:n]] + [0] * pad
    last = [max((c for c in range(n) if tile[c] == t), default=-1) for t in range(7)]
    layout = ChunkLayout(*(jnp.asarray(x, jnp.int32) for x in (tile, index, count, last)))
    tot = rng.normal(size=(nc, P)).astype(np.float32)
    want = np.zeros((nc, P), np.float32)
    for c in range(n):
        for d in range(n):
            if tile[d] == tile[c] and (index[d] > index[c] if reverse else index[d] < index[c]):
                want[c] += tot[d]
    got = np.asarray(_chunk_carry(jnp.asarray(tot), layout, kc, reverse))
    np.testing.assert_allclose(got, want, atol=1e-5)
    assert np.all(got[n:] == 0.0)
    # to the bit, the sum in the order the tracking's results were measured with: the nearest
    # chunk first (float32 rounding fixes the order)
    seq = np.zeros((nc, P), np.float32)
    for c in range(n):
        for d in range(1, kc):
            o = c + d if reverse else c - d
            if 0 <= o < n and tile[o] == tile[c]:
                seq[c] = seq[c] + tot[o]
    np.testing.assert_array_equal(got, seq)


@pytest.mark.parametrize("seed", [0, 1])
def test_blend_weights_composite_the_dense_reference_at_pixel_centres(seed):
    g = _scene(seed)
    rng = np.random.default_rng(seed)
    cam = _camera(_random_pose(rng))
    ref = _reference(g, cam, jnp.zeros(3))
    px = np.stack([rng.integers(0, W, 40), rng.integers(0, H, 40)], -1)
    w = blend_weights(project_gaussians(g, cam), px + 0.5)
    at = lambda k: np.asarray(ref[k])[px[:, 1], px[:, 0]]  # noqa: E731
    np.testing.assert_allclose(w.sum(1), at("alpha"), atol=2e-5)
    np.testing.assert_allclose(w @ np.asarray(g.features, np.float64), at("features"), atol=5e-5)
    np.testing.assert_allclose(w @ np.asarray(g.colours, np.float64), at("rgb"), atol=5e-5)
    assert (at("alpha") > 0.5).sum() > 10  # most sampled pixels are covered
