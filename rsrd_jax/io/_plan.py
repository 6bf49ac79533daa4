"""RobotPlan artefact: `plan.npz` + `plan.json`.

Arrays (K keyframes, T video frames, A approach waypoints; arm 0 = right, 1 = left):
    keyframe_indices     K        video frame of each keyframe
    q_keyframes          K×16     joints at keyframes (rad; grippers m)
    q_video              T×16     joints resampled to every video frame
    q_approach           A×16     approach segment, pre-grasp -> grasp
    tcp_target           K×2×7    TCP targets (robot base frame, wxyz_xyz)
    tcp_approach_target  A×2×7    approach TCP targets
    active               2        arm in use
    part                 2        grasped part per arm (-1 none)
    grasp_index          2        chosen grasp among the part's candidates (-1 none)
    T_part_grasp         2×7      chosen grasp in its part frame (rest-centroid frame)
    grasp_width          2        contact separation (m)
    T_robot_obj          7        object pose in the robot base frame
    position_error       2        max TCP position error over keyframes (m)
    rotation_error       2        max TCP rotation error over keyframes (rad)
    min_distance         3        smallest self / table / object distance (m)
`plan.json`: format, result (name), message, and the planner's info (chosen parts and arms,
solver results, rejection counts per stage and attempt, timings, and under "config" the
PlanConfig it was planned with). A failed plan has K = T = A = 0.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np

from ._atomic import ArtefactError, atomic_write_json, atomic_write_npz, read_json, require

PLAN_FORMAT = "rsrd_jax.plan/1"
_SHAPES = {
    "keyframe_indices": ("K",), "q_keyframes": ("K", 16), "q_video": ("T", 16), "q_approach": ("A", 16),
    "tcp_target": ("K", 2, 7), "tcp_approach_target": ("A", 2, 7), "active": (2,), "part": (2,),
    "grasp_index": (2,), "T_part_grasp": (2, 7), "grasp_width": (2,), "T_robot_obj": (7,),
    "position_error": (2,), "rotation_error": (2,), "min_distance": (3,),
}  # fmt: skip
_INT = {"keyframe_indices", "part", "grasp_index"}


def _success(self) -> bool:
    return self.result == "success"


# the fields are the arrays of `_SHAPES` (one list, not two) plus result/message/info
PlanArtefact = dataclasses.make_dataclass(
    "PlanArtefact",
    [(k, np.ndarray) for k in _SHAPES] + [("result", str), ("message", str), ("info", dict)],
    frozen=True,
    namespace={"success": property(_success), "__doc__": "A RobotPlan read from disk (numpy arrays; see the module docstring)."},
)
PlanArtefact.__module__ = __name__


def save_plan(plan, out_dir: str | Path) -> Path:
    """Writes `plan.npz` and `plan.json` into `out_dir` (each atomically).

    `plan` is an :class:`rsrd_jax.plan.RobotPlan` or a :class:`PlanArtefact` (any object with the
    array attributes above, `result_name` or `result` (str), `message` and `info`).
    """
    out = Path(out_dir)
    arrays = {}
    for k in _SHAPES:
        a = np.asarray(getattr(plan, k))
        arrays[k] = a.astype(np.int64) if k in _INT else (a.astype(bool) if k == "active" else a.astype(np.float64))
    result = getattr(plan, "result_name", None) or str(plan.result)
    atomic_write_npz(out / "plan.npz", **arrays)
    atomic_write_json(out / "plan.json", {"format": PLAN_FORMAT, "result": result, "message": plan.message,
                                          "info": plan.info})  # fmt: skip
    return out


def load_plan(path: str | Path) -> PlanArtefact:
    """Reads a RobotPlan directory (or its `plan.npz`), validating fields, shapes and values."""
    path = Path(path)
    d = path.parent if path.suffix == ".npz" else path
    npz, js = d / "plan.npz", d / "plan.json"
    if not npz.is_file():
        raise ArtefactError(f"plan not found: {npz}")
    meta = read_json(js, "plan.json")
    require(meta.get("format") == PLAN_FORMAT, js, "format", PLAN_FORMAT)
    for k in ("result", "message", "info"):
        require(k in meta, js, k, "present")
    require(isinstance(meta["result"], str), js, "result", "a string")
    dims: dict[str, int] = {}
    arrays = {}
    with np.load(npz) as z:
        for k, shape in _SHAPES.items():
            require(k in z.files, npz, k, "present")
            a = np.asarray(z[k])
            require(a.ndim == len(shape), npz, k, f"{len(shape)} dimensions")
            for s, n in zip(shape, a.shape):
                if isinstance(s, str):
                    dims.setdefault(s, n)
                    require(dims[s] == n, npz, k, f"axis {s} = {dims[s]} (as in the other arrays)")
                else:
                    require(s == n, npz, k, f"shape {shape}")
            arrays[k] = a
    ok = meta["result"] == "success"
    if ok:
        require(dims["K"] >= 2 and dims["T"] >= 1 and dims["A"] >= 2, npz, "q_keyframes", "K ≥ 2, T ≥ 1, A ≥ 2 for a successful plan")
        for k in ("q_keyframes", "q_video", "q_approach", "tcp_target", "T_robot_obj"):
            require(bool(np.all(np.isfinite(arrays[k]))), npz, k, "finite values")
        require(bool(np.any(arrays["active"])), npz, "active", "at least one arm in use")
        require(bool(np.all(np.diff(arrays["keyframe_indices"]) >= 0)), npz, "keyframe_indices", "non-decreasing")
        require(int(arrays["keyframe_indices"][-1]) < dims["T"], npz, "keyframe_indices", f"< T = {dims['T']}")
    return PlanArtefact(**arrays, result=meta["result"], message=meta["message"], info=meta["info"])
