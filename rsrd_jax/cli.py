"""`rsrd-jax`: the command-line entry point. Every stage is a subcommand; `--help` documents options.

Recipes that combine stages live here, not in the library.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")


def _add_studio_options(p: argparse.ArgumentParser) -> None:
    from .studio import StudioConfig

    d = StudioConfig()
    p.add_argument("--seed", type=int, default=d.seed, help="seed for textures, cameras, placements")
    p.add_argument("--views", type=int, default=d.scan_views, help="number of scan views (≥ 48 recommended)")
    p.add_argument("--scan-size", type=int, nargs=2, default=d.scan_size, metavar=("W", "H"), help="scan image size")
    p.add_argument("--frames", type=int, default=None, help="demo frames (default: the object's own, 90–120)")
    p.add_argument("--demo-size", type=int, nargs=2, default=d.demo_size, metavar=("W", "H"), help="demo video size")
    p.add_argument("--demo-yaw", type=float, default=None, help="object yaw in the demo relative to the scan, degrees")
    p.add_argument("--robot-size", type=int, nargs=2, default=d.robot_size, metavar=("W", "H"), help="robot view size")
    p.add_argument("--robot-xy", type=float, nargs=2, default=d.robot_object_xy, metavar=("X", "Y"),
                   help="object position on the table, robot base frame (m)")  # fmt: skip
    p.add_argument("--robot-yaw", type=float, default=None, help="object yaw on the table, degrees")
    p.add_argument("--pose-noise-deg", type=float, default=d.pose_noise_deg, help="scan pose rotation noise std (deg)")
    p.add_argument("--pose-noise-m", type=float, default=d.pose_noise_m, help="scan pose translation noise std (m)")
    p.add_argument("--clutter", action="store_true", help="scatter distractor objects around the object")
    p.add_argument("--lighting", type=float, default=d.lighting, help="light intensity multiplier")
    p.add_argument("--only", nargs="+", choices=("scan", "demo", "robot_view"), default=None, help="make only these")


def _studio_config(a: argparse.Namespace):
    from .studio import StudioConfig

    d = StudioConfig()
    return StudioConfig(
        seed=a.seed, scan_views=a.views, scan_size=tuple(a.scan_size), demo_frames=a.frames,
        demo_size=tuple(a.demo_size), demo_yaw_deg=a.demo_yaw, robot_size=tuple(a.robot_size),
        robot_object_xy=tuple(a.robot_xy), robot_object_yaw_deg=a.robot_yaw, pose_noise_deg=a.pose_noise_deg,
        pose_noise_m=a.pose_noise_m, clutter=a.clutter, lighting=a.lighting,
        parts=tuple(a.only) if a.only else d.parts,
    )  # fmt: skip


def _summary(meta: dict, out: Path) -> str:
    lines = [f"{meta['name']}: {meta['description']}  ->  {out}"]
    parts = ", ".join(f"{p['name']} ({p['joint']})" for p in meta["parts"])
    lines.append(f"  parts: {parts}; moving: {[meta['parts'][k]['name'] for k in meta['moving_parts']]}")
    lines.append(f"  {'bimanual' if meta['bimanual'] else 'single-hand'} demo; separable: {meta['separable']}")
    for k, v in meta["products"].items():
        lines.append(f"  {k}: {v}")
    t = meta["timings_s"]
    lines.append("  timings: " + ", ".join(f"{k} {v:.1f} s" for k, v in t.items()))
    return "\n".join(lines)


def cmd_studio(a: argparse.Namespace) -> int:
    from .studio import get_object, list_objects, make_object

    if a.studio_cmd == "list":
        for name in list_objects():
            obj = get_object(name)
            kind = "bimanual" if obj.bimanual else "one hand"
            print(f"{name:<12} {obj.num_parts} parts, {kind:<9} {obj.description}")
        return 0
    names = list_objects() if a.object == ["all"] else a.object
    for name in names:
        if name not in list_objects():
            print(f"error: unknown studio object {name!r}; known: {', '.join(list_objects())}", file=sys.stderr)
            return 2
    cfg = _studio_config(a)
    for name in names:
        out = Path(a.out) / name if len(names) > 1 else Path(a.out)
        if out.exists() and not a.overwrite:
            print(f"error: {out} exists; pass --overwrite to replace it", file=sys.stderr)
            return 2
        meta = make_object(name, out, cfg, overwrite=a.overwrite)
        print(_summary(meta, out))
        if a.rerun or a.sheet:
            from .viz import log_studio, studio_contact_sheet

            if a.sheet:
                print(f"  contact sheet: {studio_contact_sheet(out, out / 'contact_sheet.png')}")
            if a.rerun:
                print(f"  rerun recording: {log_studio(out, out / 'studio.rrd')}")
    return 0


def cmd_demo(a: argparse.Namespace) -> int:
    """The end-to-end demo on one embedded studio object (stages land one by one)."""
    from .studio import StudioConfig, make_object
    from .viz import log_studio, studio_contact_sheet

    out = Path(a.out)
    t0 = time.perf_counter()
    print(f"[1/1] studio: making {a.object!r} (scan, demo video, robot view) ...")
    meta = make_object(a.object, out / "studio", StudioConfig(seed=a.seed), overwrite=True)
    print(_summary(meta, out / "studio"))
    sheet = studio_contact_sheet(out / "studio", out / "contact_sheet.png")
    rrd = log_studio(out / "studio", out / "demo.rrd")
    print(f"contact sheet: {sheet}\nrerun recording: {rrd}  (view with `rerun {rrd}`)")
    print(f"demo finished in {time.perf_counter() - t0:.1f} s")
    return 0


def cmd_bench(a: argparse.Namespace) -> int:
    root = Path(__file__).resolve().parent.parent
    if not (root / "benchmarks" / "run.py").is_file():
        print("error: benchmarks/ is part of the source checkout, not the installed package", file=sys.stderr)
        return 2
    sys.path.insert(0, str(root))
    from benchmarks.run import main as bench_main

    return bench_main(a.args)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="rsrd-jax", description="Robot See Robot Do in JAX.")
    sub = parser.add_subparsers(dest="cmd", required=True)

    st = sub.add_parser("studio", help="synthetic articulated objects rendered by MuJoCo, with ground truth")
    st_sub = st.add_subparsers(dest="studio_cmd", required=True)
    st_sub.add_parser("list", help="list the studio objects")
    mk = st_sub.add_parser("make", help="make an object's scan, demo video and robot view")
    mk.add_argument("object", nargs="+", help="object name(s), or 'all'")
    mk.add_argument("--out", required=True, help="output directory (one subdirectory per object if several)")
    mk.add_argument("--overwrite", action="store_true", help="replace an existing output directory")
    mk.add_argument("--rerun", action="store_true", help="also write studio.rrd (rerun recording)")
    mk.add_argument("--sheet", action="store_true", help="also write contact_sheet.png")
    _add_studio_options(mk)
    st.set_defaults(func=cmd_studio)

    dm = sub.add_parser("demo", help="run the pipeline end to end on an embedded studio object")
    dm.add_argument("--object", default="red_box", help="studio object")
    dm.add_argument("--out", default="demo_out", help="output directory")
    dm.add_argument("--seed", type=int, default=0)
    dm.set_defaults(func=cmd_demo)

    bn = sub.add_parser("bench", help="run the benchmark suite (source checkout): args go to benchmarks.run")
    bn.add_argument("args", nargs=argparse.REMAINDER)
    bn.set_defaults(func=cmd_bench)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return int(args.func(args) or 0)


if __name__ == "__main__":
    sys.exit(main())
