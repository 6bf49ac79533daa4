"""Articulated studio objects: a small kinematic description, its MJCF and seeded textures.

An object is a tree of rigid parts. Part 0 is the root (fixed to the world at the placement
pose); every other part hangs off its parent by a hinge, a slide, or (for separable parts) a free
joint, which in MJCF makes it a top-level body. Part frames are the MuJoCo body frames, so ground
truth part poses are MuJoCo's `xpos`/`xquat`, independent of anything the project renders.
"""

from __future__ import annotations

import dataclasses
from typing import Literal

import cv2
import numpy as np

JointType = Literal["fixed", "hinge", "slide", "free"]
GeomType = Literal["box", "capsule", "sphere", "ellipsoid", "cylinder"]


@dataclasses.dataclass(frozen=True)
class Geom:
    """A primitive in its part's frame (MuJoCo sizes: half extents / radius / half length)."""

    type: GeomType
    size: tuple[float, ...]
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    euler: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Fixed-axis xyz Euler angles (radians), MuJoCo's default `eulerseq`."""
    fromto: tuple[float, ...] | None = None
    """For capsules/cylinders: segment endpoints (6 numbers), replacing pos/euler/length."""


@dataclasses.dataclass(frozen=True)
class Part:
    """A rigid part: its geoms, its joint to the parent, and a base colour for its texture."""

    name: str
    geoms: tuple[Geom, ...]
    color: tuple[float, float, float]
    parent: int | None = None
    joint: JointType = "fixed"
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Part frame origin in the parent frame at zero joint value (world/root frame for free parts)."""
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)
    """Hinge/slide axis in the part frame."""
    anchor: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Hinge anchor point in the part frame."""
    range: tuple[float, float] | None = None
    """Joint range (radians or metres)."""


@dataclasses.dataclass(frozen=True)
class Contact:
    """Where a (proxy) hand pinches a part, in that part's frame."""

    part: int
    point: tuple[float, float, float]
    """Midpoint between the fingertips."""
    pinch_axis: tuple[float, float, float]
    """Direction from thumb to index fingertip."""
    approach: tuple[float, float, float]
    """Direction from the hand towards the part (perpendicular to the pinch axis)."""
    width: float
    """Part thickness between the fingertips, metres."""


@dataclasses.dataclass(frozen=True)
class StudioObject:
    """A studio object: parts, scripted demonstration, hand contacts, paper reference."""

    name: str
    description: str
    parts: tuple[Part, ...]
    keyframes: dict[int, tuple[tuple[float, object], ...]]
    """Per moving part: (normalised time s ∈ [0, 1], joint value) keys; values are floats for
    hinges/slides and 6-vectors (xyz offset + rotation vector, in the part's rest frame) for free
    parts. Between keys the motion eases in and out (smoothstep)."""
    contacts: tuple[Contact, ...]
    """One contact per hand (right hand first); two for bimanual demos."""
    separable: bool = False
    """Parts come apart (ARAP with a small robust-loss α)."""
    num_frames: int = 90

    @property
    def num_parts(self) -> int:
        return len(self.parts)

    @property
    def bimanual(self) -> bool:
        return len(self.contacts) > 1

    def joint_values(self, s: float) -> dict[int, np.ndarray]:
        """Joint values of every moving part at normalised time `s` ∈ [0, 1]."""
        out = {}
        for part, keys in self.keyframes.items():
            times = np.array([k[0] for k in keys])
            vals = [np.atleast_1d(np.asarray(k[1], np.float64)) for k in keys]
            if s <= times[0]:
                out[part] = vals[0]
                continue
            if s >= times[-1]:
                out[part] = vals[-1]
                continue
            i = int(np.searchsorted(times, s, side="right") - 1)
            u = (s - times[i]) / (times[i + 1] - times[i])
            u = u * u * (3 - 2 * u)
            out[part] = (1 - u) * vals[i] + u * vals[i + 1]
        return out

    def validate(self) -> None:
        for i, p in enumerate(self.parts):
            if (p.parent is None) != (i == 0 or p.joint == "free"):
                raise ValueError(f"{self.name}: part {p.name!r}: only the root and free parts have no parent")
            if p.parent is not None and not 0 <= p.parent < i:
                raise ValueError(f"{self.name}: part {p.name!r}: parent must be an earlier part")
        for part in self.keyframes:
            if self.parts[part].joint == "fixed":
                raise ValueError(f"{self.name}: keyframes given for fixed part {self.parts[part].name!r}")
        for c in self.contacts:
            if not 0 <= c.part < self.num_parts:
                raise ValueError(f"{self.name}: contact on unknown part {c.part}")


# --------------------------------------------------------------------------------------------
# Textures


def part_texture(color: tuple[float, float, float], seed: int, size: int = 128) -> np.ndarray:
    """A seeded, feature-rich texture (size×size×3 uint8): base colour, blobs, stripes, speckle.

    Rich texture gives every region a distinctive appearance so features can be matched; the base
    colour keeps parts distinguishable.
    """
    rng = np.random.default_rng(seed)
    base = np.asarray(color, np.float64)
    img = np.ones((size, size, 3)) * base
    yy, xx = np.mgrid[0:size, 0:size] / size
    # low-frequency shading
    for _ in range(3):
        f = rng.uniform(1, 3, 2)
        ph = rng.uniform(0, 2 * np.pi, 2)
        img *= (0.85 + 0.15 * np.sin(2 * np.pi * (f[0] * xx + ph[0])) * np.cos(2 * np.pi * (f[1] * yy + ph[1])))[..., None]
    # coloured blobs
    for _ in range(rng.integers(10, 18)):
        c = rng.uniform(0.05, 0.95, 3)
        cx, cy = rng.uniform(0, 1, 2)
        r = rng.uniform(0.03, 0.12)
        m = ((xx - cx) ** 2 + (yy - cy) ** 2) < r * r
        img[m] = 0.4 * img[m] + 0.6 * c
    # stripes
    for _ in range(rng.integers(2, 5)):
        ang = rng.uniform(0, np.pi)
        off = rng.uniform(0, 1)
        w = rng.uniform(0.01, 0.03)
        d = np.abs(((np.cos(ang) * xx + np.sin(ang) * yy - off) % 0.25) - 0.125)
        m = d < w
        img[m] = img[m] * rng.uniform(0.2, 0.5)
    img += rng.normal(0, 0.04, img.shape)
    return (np.clip(img, 0, 1) * 255).astype(np.uint8)


def png_bytes(img: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img[..., ::-1]))
    assert ok
    return buf.tobytes()


# --------------------------------------------------------------------------------------------
# MJCF


def _fmt(v) -> str:
    return " ".join(f"{float(x):.6g}" for x in np.atleast_1d(v))


def object_mjcf(
    obj: StudioObject,
    T_world_root: np.ndarray,
    seed: int,
    prefix: str = "",
    joint_damping: float = 0.05,
    joint_frictionloss: float = 0.01,
) -> tuple[str, str, dict[str, bytes]]:
    """The object's MJCF pieces.

    Args:
        T_world_root: 4×4 pose of the root part in the world.
        seed: texture seed.
        prefix: prefix for every name (to place several objects or avoid clashes).

    Returns:
        (asset XML, worldbody XML, asset files {filename: PNG bytes}). Bodies are named
        `{prefix}part{k}`, joints `{prefix}joint{k}`, geoms `{prefix}part{k}_g{j}`.
    """
    obj.validate()
    assets, files = [], {}
    for k, p in enumerate(obj.parts):
        fname = f"{prefix}{obj.name}_part{k}.png"
        files[fname] = png_bytes(part_texture(p.color, seed * 1009 + k))
        assets.append(f'<texture name="{prefix}tex{k}" type="cube" file="{fname}"/>')
        assets.append(
            f'<material name="{prefix}mat{k}" texture="{prefix}tex{k}" specular="0.2" shininess="0.2"/>'
        )
    children: dict[int | None, list[int]] = {}
    for k, p in enumerate(obj.parts):
        children.setdefault(p.parent, []).append(k)

    def body(k: int, pos, quat, indent: str) -> str:
        p = obj.parts[k]
        lines = [f'{indent}<body name="{prefix}part{k}" pos="{_fmt(pos)}" quat="{_fmt(quat)}">']
        if p.joint == "free":
            lines.append(f'{indent}  <freejoint name="{prefix}joint{k}"/>')
        elif p.joint in ("hinge", "slide"):
            rng = f' range="{_fmt(p.range)}"' if p.range else ""
            lines.append(
                f'{indent}  <joint name="{prefix}joint{k}" type="{p.joint}" axis="{_fmt(p.axis)}" '
                f'pos="{_fmt(p.anchor)}"{rng} damping="{joint_damping}" frictionloss="{joint_frictionloss}"/>'
            )
        for j, g in enumerate(p.geoms):
            where = (
                f'fromto="{_fmt(g.fromto)}"' if g.fromto is not None else f'pos="{_fmt(g.pos)}" euler="{_fmt(g.euler)}"'
            )
            lines.append(
                f'{indent}  <geom name="{prefix}part{k}_g{j}" type="{g.type}" size="{_fmt(g.size)}" {where} '
                f'material="{prefix}mat{k}" density="300" friction="1.0 0.01 0.001" condim="4"/>'
            )
        for c in children.get(k, []):
            if obj.parts[c].joint != "free":
                lines.append(body(c, obj.parts[c].pos, (1, 0, 0, 0), indent + "  "))
        lines.append(f"{indent}</body>")
        return "\n".join(lines)

    R = T_world_root[:3, :3]
    quat_root = _mat_to_wxyz(R)
    bodies = [body(0, T_world_root[:3, 3], quat_root, "    ")]
    for k, p in enumerate(obj.parts):
        if p.joint == "free":
            # free parts start at their rest pose relative to the root
            pos_w = T_world_root[:3, :3] @ np.asarray(p.pos) + T_world_root[:3, 3]
            bodies.append(body(k, pos_w, quat_root, "    "))
    return "\n    ".join(assets), "\n".join(bodies), files


def _mat_to_wxyz(R: np.ndarray) -> np.ndarray:
    import mujoco

    q = np.zeros(4)
    mujoco.mju_mat2Quat(q, np.asarray(R, np.float64).reshape(9))
    return q
