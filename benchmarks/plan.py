"""Planning: the YuMi trajectory problem of ``rsrd_jax.plan`` (pose 5/1, limits 100, rest 0.01,
velocity 1, acceleration 0.1) and the candidate search.

Records:
1. one bimanual 50-keyframe solve (``trajectory_problem``, both arms tracking targets from a
   smooth feasible joint trajectory, start at home) with our banded LM, and jaxopt's dense LM
   (Cholesky, materialised Jacobian; plus optimistix QR unless quick) on the same residual vector:
   time to the final cost, compile apart, and whether the dense solver reached the same cost;
2. a vmapped batch of 480 grasp candidates (quick: 32) of a single-arm problem, 50 keyframes
   (quick: 10), our solver;
3. ``plan_robot`` end to end on a synthetic moving cube with 480 (quick 32) grasps (search +
   approach + checks), first call (compile) and second call apart.
The solver-only comparison on a similar problem is in ``benchmarks/lm.py``.
"""

from __future__ import annotations

import sys
import time

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from benchmarks._util import measure, record

BENCH = "plan"


def _targets(robot, K: int, key):
    from rsrd_jax.robot import tcp_poses

    ts = jnp.linspace(0.0, 1.0, K)[:, None]
    k1, k2 = jax.random.split(key)
    amp = 0.3 * jax.random.uniform(k1, (16,)).at[14:].set(0.0)
    phase = jax.random.uniform(k2, (16,), maxval=2 * np.pi)
    q = robot.home + amp * (jnp.sin(2.0 * ts + phase) - jnp.sin(phase))
    return tcp_poses(robot, q)


def run(quick: bool) -> list[dict]:
    from rsrd_jax.plan import (
        CostParams, CostWeights, LMResult, PlanConfig, PoseData, SolverConfig, TerminationConfig,
        TrustRegionConfig, plan_robot, problem_data, strip_robot, trajectory_problem,
    )  # fmt: skip
    from rsrd_jax.robot import load_yumi

    robot = load_yumi()
    lite = strip_robot(robot)
    recs: list[dict] = []
    K = 50
    params = CostParams(lite, CostWeights(acceleration=0.1), None)
    prob = trajectory_problem(True, False)
    pose = PoseData(_targets(lite, K, jax.random.key(0)), jnp.ones((K, 2)))
    data = problem_data(pose, K, True)
    x0 = jnp.tile(lite.home, (K, 1))
    cfg = SolverConfig(TrustRegionConfig(lambda_initial=0.1), TerminationConfig(max_iterations=100))
    from rsrd_jax.plan import solve_lm

    solve = lambda x: solve_lm(prob, x, data, params, cfg)  # noqa: E731
    c_s, ms = measure(solve, x0, repeat=2 if quick else 5)
    sol = solve(x0)
    ours = float(sol.cost)
    case = dict(keyframes=K, dof=16, arms=2)
    recs.append(record(BENCH, dict(case, solver="banded LM (ours)"), ms, c_s, dict(
        final_cost=ours, iterations=int(sol.iterations), converged=bool(sol.result == LMResult.converged))))

    import jaxopt

    flat = lambda v: prob.residual_vector(v.reshape(x0.shape), data, params)  # noqa: E731
    lm = jaxopt.LevenbergMarquardt(residual_fun=flat, maxiter=100, tol=1e-4, solver="cholesky", materialize_jac=True)
    fn = jax.jit(lambda v: lm.run(v).params)
    c2, ms2 = measure(fn, x0.reshape(-1), repeat=1)
    c = float(jnp.sum(flat(fn(x0.reshape(-1))) ** 2))
    recs.append(record(BENCH, dict(case, solver="jaxopt LM dense Cholesky"), ms2, c2, dict(
        final_cost=c, same_cost_as_ours=bool(abs(c - ours) <= 1e-2 * max(ours, 1e-9)), speedup_of_ours=ms2 / ms)))
    if not quick:
        import optimistix as optx

        sv = optx.LevenbergMarquardt(rtol=1e-6, atol=1e-6)
        fo = jax.jit(lambda v: optx.least_squares(lambda y, _: flat(y), sv, v, max_steps=200, throw=False).value)
        c3, ms3 = measure(fo, x0.reshape(-1), repeat=1)
        c = float(jnp.sum(flat(fo(x0.reshape(-1))) ** 2))
        recs.append(record(BENCH, dict(case, solver="optimistix LM dense QR"), ms3, c3, dict(
            final_cost=c, same_cost_as_ours=bool(abs(c - ours) <= 1e-2 * max(ours, 1e-9)), speedup_of_ours=ms3 / ms)))

    # batch of single-arm candidates
    n = 32 if quick else 480
    Kb = 10 if quick else 50
    tg = _targets(lite, Kb, jax.random.key(1))
    off = 0.03 * jax.random.normal(jax.random.key(2), (n, 3))
    tgs = jnp.broadcast_to(tg, (n, *tg.shape)).at[..., 0, 4:].add(off[:, None])
    act = jnp.broadcast_to(jnp.asarray([1.0, 0.0]), (n, Kb, 2))
    probs = trajectory_problem(False, False)
    bcfg = SolverConfig(TrustRegionConfig(lambda_initial=0.1), TerminationConfig(max_iterations=50))
    batched = jax.jit(jax.vmap(lambda x, t, a: solve_lm(probs, x, problem_data(PoseData(t, a), Kb), params, bcfg)))
    x0s = jnp.tile(lite.home, (n, Kb, 1))
    c_s, b_ms = measure(batched, x0s, tgs, act, repeat=1)
    out = batched(x0s, tgs, act)
    recs.append(record(BENCH, dict(keyframes=Kb, batch=n, solver="banded LM vmapped, single arm"), b_ms, c_s, dict(
        ms_per_candidate=b_ms / n, converged_fraction=float(jnp.mean(out.result == LMResult.converged)),
        iterations_max=int(jnp.max(out.iterations)))))  # fmt: skip

    # plan_robot end to end on a synthetic moving cube
    sys.path.insert(0, "tests")
    from test_plan import T_ROBOT_OBJ, _cube, _grasps, _trajectory

    cfgp = PlanConfig(num_keyframes=Kb, approach_steps=Kb, chunk_size=n, parts=(0,), arms=(0,), max_iterations=50)
    args = (robot, [_cube()], _trajectory(60), T_ROBOT_OBJ)
    g = {0: _grasps(n, 0)}
    t0 = time.perf_counter()
    p = plan_robot(*args, grasps=g, config=cfgp)
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    p = plan_robot(*args, grasps=g, config=cfgp)
    second = (time.perf_counter() - t0) * 1e3
    recs.append(record(BENCH, dict(keyframes=Kb, grasps=n, solver="plan_robot (search + approach)"), second,
                       max(first - second / 1e3, 0.0), dict(result=p.result_name, rejections=p.info["rejections"],
                       max_pos_err_mm=float(1e3 * np.nanmax(p.position_error)))))  # fmt: skip
    for r in recs:
        print(f"[plan] {r['case']}: {r['median_ms']:.1f} ms (compile {r['compile_s']:.1f} s) {r['metrics']}", file=sys.stderr)
    return recs


if __name__ == "__main__":
    import json

    for r in run(quick="--quick" in sys.argv):
        print(json.dumps(r, default=str))
