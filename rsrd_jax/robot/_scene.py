"""Scene assembly: robot + table + an optional studio object attached at a pose."""

from __future__ import annotations

import mujoco
import numpy as np

from ._constants import SCENE_XML


def build_scene_spec(
    object_xml: str | None = None,
    pos: tuple[float, float, float] | np.ndarray = (0.45, 0.0, -0.1),
    quat_wxyz: tuple[float, float, float, float] | np.ndarray = (1.0, 0.0, 0.0, 0.0),
    prefix: str = "obj/",
) -> mujoco.MjSpec:
    """Robot + table scene (``models/yumi_mjcf/scene.xml``), optionally with an object.

    Args:
        object_xml: MJCF of the object: either one or more ``<body>`` elements (e.g.
            ``'<body name="box"><freejoint/><geom type="box" size=".02 .02 .02"/></body>'``) or a
            whole ``<mujoco>`` document whose worldbody children are attached (its assets and
            defaults come along). ``None`` gives robot + table only.
        pos: position (m, world frame) of the frame the object's bodies are attached to. The table
            top is at z = TABLE_TOP_Z = -0.1.
        quat_wxyz: orientation of that frame.
        prefix: prefix added to every name of the object (avoids clashes with robot names).

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
        text = f'<mujoco model="object"><worldbody>{text}</worldbody></mujoco>'
    try:
        child = mujoco.MjSpec.from_string(text)
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
