"""The CLI and the benchmark runner, end to end on tiny sizes."""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from rsrd_jax.cli import main

ROOT = Path(__file__).resolve().parent.parent


def test_studio_list(capsys):
    assert main(["studio", "list"]) == 0
    out = capsys.readouterr().out
    assert "red_box" in out and "frog" in out and "bimanual" in out


def test_studio_make_tiny_with_sheet_and_rerun(tmp_path, capsys):
    args = ["studio", "make", "scissors", "--out", str(tmp_path / "s"), "--views", "3", "--scan-size", "64", "48",
            "--frames", "3", "--demo-size", "64", "48", "--robot-size", "96", "54", "--sheet", "--rerun"]  # fmt: skip
    assert main(args) == 0
    out = capsys.readouterr().out
    assert "scissors" in out and "timings" in out
    for f in ("object.json", "contact_sheet.png", "studio.rrd", "scan/transforms.json", "demo/demo.mp4", "robot_view/rgb.png"):
        assert (tmp_path / "s" / f).is_file(), f
    assert (tmp_path / "s" / "studio.rrd").stat().st_size > 1000
    # a second run refuses to overwrite the user's directory
    assert main(args) == 2
    assert "exists" in capsys.readouterr().err


def test_studio_make_unknown_object(tmp_path, capsys):
    assert main(["studio", "make", "teapot", "--out", str(tmp_path / "t")]) == 2
    assert "unknown studio object 'teapot'" in capsys.readouterr().err
    assert not (tmp_path / "t").exists()


def test_benchmark_runner_writes_records(tmp_path):
    out = tmp_path / "bench.json"
    proc = subprocess.run(
        [sys.executable, "-m", "benchmarks.run", "studio", "--quick", "--json", str(out)],
        cwd=ROOT, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    records = json.loads(out.read_text())
    assert len(records) >= 2
    for r in records:
        for k in ("bench", "case", "median_ms", "compile_s", "peak_rss_mb", "metrics", "versions", "device"):
            assert k in r
        assert r["median_ms"] > 0 and r["device"]["platform"] == "cpu"
    assert "median ms" in proc.stdout


def test_benchmark_runner_rejects_unknown_name():
    proc = subprocess.run([sys.executable, "-m", "benchmarks.run", "nope"], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode != 0 and "unknown benchmark" in proc.stderr


def test_compilation_cache_stores_and_can_be_turned_off(tmp_path):
    """`rsrd-jax` turns on JAX's persistent compilation cache (a later process loads the tracker's
    and planner's compiled functions instead of compiling them again); the environment variable
    turns it off."""
    import os

    code = (
        "import sys, jax, jax.numpy as jnp\n"
        "from rsrd_jax._cache import enable_compilation_cache\n"
        "d = enable_compilation_cache(sys.argv[1], min_compile_time_s=0.0)\n"
        "print(d)\n"
        "jax.jit(lambda x: jnp.sin(x) @ x.T)(jnp.ones((8, 8))).block_until_ready()\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("RSRD_JAX_NO_COMPILE_CACHE", "JAX_COMPILATION_CACHE_DIR")}
    on = subprocess.run([sys.executable, "-c", code, str(tmp_path / "on")], env=env, capture_output=True, text=True, check=True)
    assert on.stdout.strip() == str(tmp_path / "on")
    assert any(p.is_file() for p in (tmp_path / "on").rglob("*")), "nothing was stored"
    env["RSRD_JAX_NO_COMPILE_CACHE"] = "1"
    off = subprocess.run([sys.executable, "-c", code, str(tmp_path / "off")], env=env, capture_output=True, text=True, check=True)
    assert off.stdout.strip() == "None" and not (tmp_path / "off").exists()


def test_compile_clock_counts_compilation_and_not_compiled_calls():
    """`CompileClock` adds up JAX's compile events inside its block: a first call of a new jitted
    function takes seconds of tracing and XLA compilation (at least the part of the call's wall
    time they account for); a second call of the compiled function, none; a listener left after
    the block would keep counting."""
    import time

    import jax
    import jax.numpy as jnp

    from rsrd_jax._cache import CompileClock

    f = jax.jit(lambda x: jnp.cumsum(jnp.sin(x) @ x.T, axis=0) * 3.0 + 1.0)
    x = jnp.ones((64, 64))
    with CompileClock() as first:
        t0 = time.perf_counter()
        f(x).block_until_ready()
        wall = time.perf_counter() - t0
    assert 0.0 < first.seconds <= wall
    with CompileClock() as again:
        f(x).block_until_ready()
    assert again.seconds == 0.0
    seen = first.seconds
    jax.jit(lambda x: jnp.tanh(x) + 2.0)(x).block_until_ready()  # compiled after the block
    assert first.seconds == seen


def test_plan_approach_clearance_rejects_bad_values(tmp_path, capsys):
    """``--approach-clearance`` takes metres or 'open'; anything else is an argparse error naming
    the value, before any file is read."""
    for bad in ("wide", "-0.01", "nan"):
        with pytest.raises(SystemExit) as e:
            main(["plan", str(tmp_path / "model"), str(tmp_path / "traj"), "--object-pose", "0", "0", "0", "0",
                  "--out", str(tmp_path / "p"), "--approach-clearance", "open", bad])  # fmt: skip
        assert e.value.code == 2
        assert repr(bad) in capsys.readouterr().err
    assert not (tmp_path / "p").exists()


def test_plan_studio_gt_names_the_missing_ground_truth(tmp_path, capsys):
    """``plan --studio-gt DIR`` on a studio directory without its robot view (made with
    ``--only scan demo``, or not a studio directory at all) is an error naming the missing file,
    exit code 2, no traceback and no output written."""
    (tmp_path / "st" / "scan" / "gt").mkdir(parents=True)
    (tmp_path / "st" / "scan" / "gt" / "scan_gt.npz").write_bytes(b"")
    assert main(["plan", "--studio-gt", str(tmp_path / "st"), "--out", str(tmp_path / "p")]) == 2
    err = capsys.readouterr().err
    assert "robot_view/gt.json" in err and "demo/gt/part_poses.npz" in err and "scan_gt.npz" not in err
    assert not (tmp_path / "p").exists()
