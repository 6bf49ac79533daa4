"""Artefact readers/writers: round trips, atomicity and clear errors."""

import json

import jaxlie
import jax
import numpy as np
import pytest

from rsrd_jax.geometry import Intrinsics, look_at
from rsrd_jax.io import (
    ArtefactError,
    atomic_replace_dir,
    atomic_write_image,
    atomic_write_text,
    read_capture,
    read_demo,
    read_depth_png,
    read_video,
    write_camera_json,
    write_depth_png,
    write_label_png,
    write_transforms,
    write_video,
)


def _tiny_capture(root, n=3, size=(16, 12)):
    K = Intrinsics.create(20.0, 21.0, size[0] / 2, size[1] / 2, *size)
    Ts, files = [], []
    for i in range(n):
        T = np.asarray(look_at([0.5 * np.cos(i), 0.5 * np.sin(i), 0.3], [0, 0, 0]).as_matrix(), np.float64)
        Ts.append(T)
        atomic_write_image(root / f"images/{i}.png", np.full((size[1], size[0], 3), 10 * i, np.uint8))
        write_depth_png(root / f"depth/{i}.png", np.full((size[1], size[0]), 0.4 + 0.1 * i))
        write_label_png(root / f"parts/{i}.png", np.full((size[1], size[0]), i % 2 + 1, np.uint8))
        files.append({"file_path": f"images/{i}.png", "depth_file_path": f"depth/{i}.png", "part_mask_path": f"parts/{i}.png"})
    write_transforms(root, K, np.stack(Ts), files)
    return K, np.stack(Ts)


def test_capture_round_trip(tmp_path):
    K, Ts = _tiny_capture(tmp_path)
    cap = read_capture(tmp_path)
    assert len(cap) == 3 and cap.has_depth and cap.has_part_masks
    assert (cap.intrinsics.width, cap.intrinsics.height) == (16, 12)
    assert float(cap.intrinsics.fy) == pytest.approx(21.0)
    np.testing.assert_allclose(cap.T_cam_world(), Ts, atol=1e-5)
    assert cap.image(2).shape == (12, 16, 3) and cap.image(2)[0, 0, 0] == 20
    np.testing.assert_allclose(cap.depth(1), 0.5, atol=1e-3)
    assert cap.part_mask(0).max() == 1
    # written in OpenGL convention: camera looks down its -z axis at the origin
    meta = json.loads((tmp_path / "transforms.json").read_text())
    c2w = np.asarray(meta["frames"][0]["transform_matrix"])
    to_origin = -c2w[:3, 3] / np.linalg.norm(c2w[:3, 3])
    np.testing.assert_allclose(-c2w[:3, 2], to_origin, atol=1e-5)


def _edit(tmp_path, fn):
    p = tmp_path / "transforms.json"
    meta = json.loads(p.read_text())
    fn(meta)
    p.write_text(json.dumps(meta))


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda m: m["frames"][0].update(file_path="images/missing.png"), "file not found"),
        (lambda m: m["frames"][1]["transform_matrix"][0].__setitem__(0, float("nan")), "finite"),
        (lambda m: m["frames"][1].update(transform_matrix=(2 * np.eye(4)).tolist()), "rigid"),
        (lambda m: m.update(k1=0.1), "k1"),
        (lambda m: m.pop("fl_x"), "fl_x"),
        (lambda m: m.update(frames=[]), "frames"),
        (lambda m: m["frames"][0].update(fl_x=99.0), "per-frame"),
    ],
)
def test_bad_captures_name_file_and_field(tmp_path, edit, match):
    _tiny_capture(tmp_path)
    _edit(tmp_path, edit)
    with pytest.raises(ArtefactError, match=match) as e:
        read_capture(tmp_path)
    assert "transforms.json" in str(e.value)


def test_capture_image_size_mismatch_and_missing_dir(tmp_path):
    _tiny_capture(tmp_path)
    atomic_write_image(tmp_path / "images/1.png", np.zeros((5, 5, 3), np.uint8))
    cap = read_capture(tmp_path)
    with pytest.raises(ArtefactError, match="w=16, h=12"):
        cap.image(1)
    with pytest.raises(ArtefactError, match="not found"):
        read_capture(tmp_path / "nope")


def test_depth_png_millimetres(tmp_path):
    d = np.array([[0.0, 0.1234], [np.nan, 65.0]])
    write_depth_png(tmp_path / "d.png", d)
    back = read_depth_png(tmp_path / "d.png")
    np.testing.assert_allclose(back, [[0.0, 0.123], [0.0, 65.0]], atol=1e-6)
    with pytest.raises(ArtefactError, match="16-bit"):
        atomic_write_image(tmp_path / "rgb.png", np.zeros((2, 2, 3), np.uint8))
        read_depth_png(tmp_path / "rgb.png")


def test_atomic_write_keeps_old_file_on_failure(tmp_path):
    p = atomic_write_text(tmp_path / "a.txt", "old")

    def boom(tmp):
        (tmp / "x").write_text("partial")
        raise RuntimeError("crash")

    with pytest.raises(RuntimeError):
        atomic_replace_dir(tmp_path / "dir", boom)
    assert not (tmp_path / "dir").exists()
    assert p.read_text() == "old"
    atomic_replace_dir(tmp_path / "dir", lambda t: (t / "f").write_text("1"))
    atomic_replace_dir(tmp_path / "dir", lambda t: (t / "g").write_text("2"))
    assert [f.name for f in (tmp_path / "dir").iterdir()] == ["g"]
    assert not [f for f in tmp_path.iterdir() if f.name.startswith(".")]


def test_video_round_trip_and_corrupt_video(tmp_path):
    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (24, 32, 3)).astype(np.uint8)
    base = np.kron(base[::4, ::4], np.ones((4, 4, 1), np.uint8))  # blocky: survives compression
    frames = np.stack([np.roll(base, t, axis=1) for t in range(5)])
    write_video(tmp_path / "v.mp4", frames, fps=30)
    back, fps = read_video(tmp_path / "v.mp4")
    assert back.shape == frames.shape and fps == pytest.approx(30)
    assert np.abs(back.astype(int) - frames).mean() < 25
    (tmp_path / "bad.mp4").write_bytes(b"\x00\x01not a video" * 10)
    with pytest.raises(ArtefactError, match="bad.mp4"):
        read_video(tmp_path / "bad.mp4")


def test_demo_camera_mismatch_and_missing(tmp_path):
    write_video(tmp_path / "demo.mp4", np.zeros((2, 24, 32, 3), np.uint8))
    with pytest.raises(ArtefactError, match="camera.json"):
        read_demo(tmp_path / "demo.mp4")
    write_camera_json(tmp_path / "camera.json", Intrinsics.create(30.0, 30.0, 20.0, 15.0, 40, 30))
    with pytest.raises(ArtefactError, match="40×30"):
        read_demo(tmp_path / "demo.mp4")
    write_camera_json(tmp_path / "camera.json", Intrinsics.create(30.0, 30.0, 16.0, 12.0, 32, 24))
    demo = read_demo(tmp_path)
    assert demo.num_frames == 2 and demo.intrinsics.width == 32
