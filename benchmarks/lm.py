"""Sparse block-banded LM (rsrd_jax.plan.solve_lm) vs optimistix / jaxopt dense LM.

Problem: the bimanual YuMi trajectory problem of the RSRD planner: 50 keyframes x 16 DoF (both
arms and grippers), residuals per keyframe = both TCP poses (position weight 5, rotation 1) +
joint-limit hinge (100) + rest pose (0.01); velocity smoothness (1.0, bandwidth 1) and
acceleration smoothness (0.1, bandwidth 2). Targets are the TCP poses of a smooth, feasible joint
trajectory near the home pose; every solver starts at the home pose.

Records: our solver on one problem; the dense solvers on the same problem, stopped by tolerance
and checked to reach the same final cost ("time to the same final cost"); our solver vmapped over
a batch of candidate problems (480, quick 32: targets shifted by a random offset per candidate,
like grasp candidates) with the ``while`` and the masked fixed-iteration ``scan`` loop.
Compile time is reported apart (first call).
"""

from __future__ import annotations

import os
import sys
import time

import jax
import jax.numpy as jnp
import jaxlie
import numpy as np

from benchmarks._util import measure, record
from rsrd_jax.plan import BandedProblem, Cost, LMResult, SolverConfig, TerminationConfig, solve_lm

BENCH = "lm"
T_KEYFRAMES = 50
WEIGHTS = dict(w_pos=5.0, w_rot=1.0, w_limit=100.0, w_rest=0.01, w_vel=1.0, w_acc=0.1)


def yumi_problem(model):
    """The bimanual YuMi trajectory problem as a BandedProblem (cost functions close over the
    robot model; weights are passed as ``params``)."""
    from rsrd_jax.robot import tcp_poses

    def pose_limits_rest(q, target, p):
        T_tcp = jaxlie.SE3(tcp_poses(model, q, check_finite=False))
        T_target = jaxlie.SE3(target)
        pos = T_tcp.translation() - T_target.translation()
        rot = (T_target.rotation().inverse() @ T_tcp.rotation()).log()
        limit = jax.nn.relu(q - model.upper) + jax.nn.relu(model.lower - q)
        return jnp.concatenate(
            [
                p["w_pos"] * pos.reshape(-1),
                p["w_rot"] * rot.reshape(-1),
                p["w_limit"] * limit,
                p["w_rest"] * (q - model.home),
            ]
        )

    def velocity(qw, _, p):
        return p["w_vel"] * (qw[1] - qw[0])

    def acceleration(qw, _, p):
        return p["w_acc"] * (qw[2] - 2.0 * qw[1] + qw[0])

    return BandedProblem(
        costs=(
            Cost(pose_limits_rest, 0, "pose_limits_rest"),
            Cost(velocity, 1, "velocity"),
            Cost(acceleration, 2, "acceleration"),
        )
    )


def yumi_targets(model, T: int, key):
    """TCP targets (T, 2, 7) from a smooth joint trajectory near home, and that trajectory."""
    from rsrd_jax.robot import tcp_poses

    ts = jnp.linspace(0.0, 1.0, T)[:, None]
    k1, k2 = jax.random.split(key)
    amp = 0.3 * jax.random.uniform(k1, (16,)).at[14:].set(0.0)
    phase = jax.random.uniform(k2, (16,), maxval=2 * np.pi)
    q_true = model.home + amp * (jnp.sin(2.0 * ts + phase) - jnp.sin(phase))
    return tcp_poses(model, q_true), q_true


def _log(rec: dict) -> dict:
    """Print a record as soon as it exists (the runs are long on a shared CPU)."""
    print(f"[lm] {rec['case'].get('solver')}: {rec['median_ms']:.1f} ms (compile {rec['compile_s']:.1f} s) "
          f"{rec['metrics']}", file=sys.stderr, flush=True)
    return rec


def _shift_targets(targets, offsets):
    """Translate both TCP targets of every keyframe by a per-candidate offset (grasp stand-in)."""
    return targets.at[..., 4:].add(offsets[:, None, None, :])


def run(quick: bool) -> list[dict]:
    from rsrd_jax.robot import load_yumi

    model = load_yumi()
    problem = yumi_problem(model)
    params = {k: jnp.float32(v) for k, v in WEIGHTS.items()}
    targets, _ = yumi_targets(model, T_KEYFRAMES, jax.random.key(0))
    data = (targets, None, None)
    x0 = jnp.tile(model.home, (T_KEYFRAMES, 1))
    case = dict(T=T_KEYFRAMES, dof=16, residuals=int(problem.residual_vector(x0, data, params).size))
    records: list[dict] = []

    def add(rec: dict) -> None:
        rec["metrics"]["loadavg_1min"] = os.getloadavg()[0]
        records.append(_log(rec))

    # --- ours, one problem ---------------------------------------------------------------------
    cfg = SolverConfig(termination=TerminationConfig(max_iterations=100))
    solve = lambda x0: solve_lm(problem, x0, data, params, cfg)  # noqa: E731
    compile_s, ms = measure(solve, x0, repeat=3 if quick else 10)
    sol = solve(x0)
    ours_cost = float(sol.cost)
    add(
        record(
            BENCH,
            dict(case, solver="sparse_lm (ours, block-banded Cholesky)"),
            ms,
            compile_s,
            dict(
                final_cost=ours_cost,
                iterations=int(sol.iterations),
                converged=bool(sol.result == LMResult.converged),
                ms_per_iteration=ms / max(int(sol.iterations), 1),
            ),
        )
    )

    # --- dense references on the same problem ---------------------------------------------------
    import jaxopt
    import lineax as lx
    import optimistix as optx

    flat_res = lambda v: problem.residual_vector(v.reshape(x0.shape), data, params)  # noqa: E731
    # Quick mode keeps the fastest dense reference only (each dense solve takes seconds here).
    refs = {"jaxopt LM (dense Cholesky)": None}
    if not quick:
        refs["optimistix LM (dense QR, default)"] = lambda: optx.LevenbergMarquardt(rtol=1e-6, atol=1e-6)
        refs["optimistix LM (dense Cholesky normal eq.)"] = lambda: optx.LevenbergMarquardt(
            rtol=1e-6, atol=1e-6, linear_solver=lx.Normal(lx.Cholesky())
        )
        refs["optimistix LM (matrix-free normal CG)"] = lambda: optx.LevenbergMarquardt(
            rtol=1e-6, atol=1e-6, linear_solver=lx.NormalCG(rtol=1e-4, atol=1e-6)
        )
        refs["jaxopt LM (matrix-free CG, default)"] = "cg"
    for name, make in refs.items():
        if make is None or make == "cg":
            # jaxopt's default linear solver is matrix-free CG (jaxopt.linear_solve.solve_cg).
            kw = dict(solver="cholesky", materialize_jac=True) if make is None else {}
            lm = jaxopt.LevenbergMarquardt(residual_fun=flat_res, maxiter=40, tol=1e-3, **kw)
            fn = jax.jit(lambda v, lm=lm: (lambda o: (o.params, o.state.iter_num))(lm.run(v)))
        else:
            solver = make()
            fn = jax.jit(
                lambda v, solver=solver: (
                    lambda o: (o.value, o.stats["num_steps"])
                )(optx.least_squares(lambda y, _: flat_res(y), solver, v, max_steps=100, throw=False))
            )
        outs = []
        keep = lambda v, fn=fn: outs.append(fn(v)) or outs[-1]  # noqa: E731  (no extra dense run)
        c_s, r_ms = measure(keep, x0.reshape(-1), repeat=1 if quick else 3)
        y, steps = outs[-1]
        c = float(jnp.sum(flat_res(y) ** 2))
        add(
            record(
                BENCH,
                dict(case, solver=name),
                r_ms,
                c_s,
                dict(
                    final_cost=c,
                    iterations=int(steps),
                    same_cost_as_ours=bool(abs(c - ours_cost) <= 1e-3 * ours_cost),
                    speedup_of_ours=r_ms / ms,
                ),
            )
        )

    # --- batches of candidate problems ----------------------------------------------------------
    n = 32 if quick else 480
    offsets = 0.03 * jax.random.normal(jax.random.key(1), (n, 3))
    batch_targets = _shift_targets(jnp.broadcast_to(targets, (n, *targets.shape)), offsets)
    x0s = jnp.broadcast_to(x0, (n, *x0.shape))
    # "while": the batch runs until its slowest member stops; "scan": exactly max_iterations
    # masked passes (a fixed budget; unfinished members report max_iterations).
    for loop, max_it in (("while", 100), ("scan", 10)):
        bcfg = SolverConfig(loop=loop, termination=TerminationConfig(max_iterations=max_it))
        batched = jax.jit(
            jax.vmap(lambda x, t, bcfg=bcfg: solve_lm(problem, x, (t, None, None), params, bcfg))
        )
        c_s, b_ms = measure(batched, x0s, batch_targets, repeat=1 if quick else 2)
        out = batched(x0s, batch_targets)
        add(
            record(
                BENCH,
                dict(case, solver=f"sparse_lm vmap ({loop}, max_iterations={max_it})", batch=n),
                b_ms,
                c_s,
                dict(
                    ms_per_candidate=b_ms / n,
                    converged_fraction=float(jnp.mean(out.result == LMResult.converged)),
                    iterations_max=int(jnp.max(out.iterations)),
                    iterations_mean=float(jnp.mean(out.iterations)),
                    cost_median=float(jnp.median(out.cost)),
                ),
            )
        )
    # sequential baseline for the batch: one jitted single solve per candidate
    t0 = time.perf_counter()
    m = min(n, 8)
    for i in range(m):
        jax.block_until_ready(solve_lm(problem, x0, (batch_targets[i], None, None), params, cfg))
    seq_ms = (time.perf_counter() - t0) * 1e3 / m
    add(
        record(
            BENCH,
            dict(case, solver="sparse_lm sequential single solves", batch=m),
            seq_ms * m,
            0.0,
            dict(ms_per_candidate=seq_ms),
        )
    )
    return records


if __name__ == "__main__":
    import json

    for r in run(quick="--quick" in sys.argv):
        print(json.dumps(r))
