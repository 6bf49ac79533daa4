"""Scene assembly: robot + table + an optional studio object attached at a pose."""

from __future__ import annotations

import mujoco
import numpy as np

from ._constants import SCENE_XML


def build_scene_spec(
    object_xml: str | None = None,
    pos: tuple[float, float, float] | np.ndarray = (0.45, 0.0, 0.0),
    quat_wxyz: tuple[float, float, float, float] | np.ndarray = (1.0, 0.0, 0.0, 0.0),
    prefix: str = "obj/",
    asset_xml: str = "",
    assets: dict[str, bytes] | None = None,
) -> mujoco.MjSpec:
    """Robot + table scene (``models/yumi_mjcf/scene.xml``), optionally with an object.

    Args:
        object_xml: MJCF of the object: either one or more ``<body>`` elements (e.g.
            ``'<body name="box"><freejoint/><geom type="box" size=".02 .02 .02"/></body>'``) or a
            whole ``<mujoco>`` document whose worldbody children are attached (its assets and
            defaults come along). ``None`` gives robot + table only.
        pos: position (m, world frame) of the frame the object's bodies are attached to. The table
            top is at z = TABLE_TOP_Z = 0.
        quat_wxyz: orientation of that frame.
        prefix: prefix added to every name of the object (avoids clashes with robot names).
        asset_xml: extra ``<asset>`` children (textures, materials, meshes) used by the bodies, e.g.
            the first output of ``rsrd_jax.studio.object_mjcf``.
        assets: in-memory files referenced by the assets ({filename: bytes}).

    Returns:
        An uncompiled ``mujoco.MjSpec``; call ``.compile()`` for an ``MjModel`` or ``.to_xml()``.

    Raises:
        ValueError: if ``object_xml`` is not valid MJCF or has no body.
    """
    spec = mujoco.MjSpec.from_file(str(SCENE_XML))
    if object_xml is None:
        return spec
    text = object_xml.strip()
    if not text.startswith("<mujoco"):
        text = (f'<mujoco model="object"><asset>{asset_xml}</asset>'
                f'<worldbody>{text}</worldbody></mujoco>')
    try:
        child = mujoco.MjSpec.from_string(text, assets=assets or {})
    except Exception as e:  # mujoco raises a plain ValueError with the parser message
        raise ValueError(f"object_xml is not valid MJCF: {e}") from e
    bodies = list(child.worldbody.bodies)
    if not bodies:
        raise ValueError("object_xml has no <body> under its worldbody")
    frame = spec.worldbody.add_frame(
        pos=np.asarray(pos, float).tolist(), quat=np.asarray(quat_wxyz, float).tolist()
    )
    spec.attach(child, frame=frame, prefix=prefix)
    return spec


def build_scene_xml(object_xml: str | None = None, **kwargs) -> str:
    """Same as :func:`build_scene_spec` but returns a self-contained MJCF string (compiled once to
    validate it). Keyword arguments are those of ``build_scene_spec``."""
    spec = build_scene_spec(object_xml, **kwargs)
    spec.compile()
    return spec.to_xml()


def servo_ctrl(model, q_ref: np.ndarray, qdot_ref: np.ndarray | None = None) -> np.ndarray:
    """MuJoCo ``ctrl`` that makes the position servos track a joint reference (host, numpy).

    A position actuator applies kp (ctrl - q) - kv qdot; commanding
    ctrl = q_ref + (kv / kp) qdot_ref turns it into the PD law kp (q_ref - q) + kv (qdot_ref - qdot),
    which removes the velocity-proportional lag of a plain position command.

    Args:
        model: a :class:`YumiModel` (its ``mj_model`` gives the gains and actuator order).
        q_ref: (16,) reference in JOINT_NAMES order (rad; grippers in m).
        qdot_ref: (16,) reference velocity, or None for zero.

    Returns:
        (nu,) control vector (robot actuators filled, any other actuators 0), clipped to ctrlrange.
    """
    from ._constants import JOINT_NAMES

    m = model.mj_model
    q_ref = np.asarray(q_ref, float)
    qdot_ref = np.zeros(16) if qdot_ref is None else np.asarray(qdot_ref, float)
    if q_ref.shape != (16,) or qdot_ref.shape != (16,):
        raise ValueError(f"q_ref and qdot_ref must have shape (16,); got {q_ref.shape}, {qdot_ref.shape}")
    ctrl = np.zeros(m.nu)
    names = [f"act_{n}" for n in JOINT_NAMES[:14]] + ["act_gripper_r", "act_gripper_l"]
    for k, name in enumerate(names):
        a = m.actuator(name).id
        kp, kv = m.actuator_gainprm[a, 0], -m.actuator_biasprm[a, 2]
        ctrl[a] = np.clip(q_ref[k] + kv / kp * qdot_ref[k], *m.actuator_ctrlrange[a])
    return ctrl
