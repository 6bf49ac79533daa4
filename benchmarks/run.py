"""Benchmark runner: `python -m benchmarks.run [NAME ...] [--quick] [--json PATH]`.

Every module `benchmarks/<name>.py` (not starting with `_`) exposing `run(quick: bool) -> list[dict]`
is a benchmark. Each runs in its own subprocess so that peak memory is per benchmark; records get
the library versions and the device kind, are printed as a table and written as a JSON list.
"""

from __future__ import annotations

import argparse
import importlib
import json
import os
import pkgutil
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

_HERE = Path(__file__).resolve().parent


def available() -> list[str]:
    """Names of the benchmark modules in this folder."""
    return sorted(
        m.name
        for m in pkgutil.iter_modules([str(_HERE)])
        if not m.name.startswith("_") and m.name != "run"
    )


def versions() -> dict:
    import jax

    out = {"python": platform.python_version(), "jax": jax.__version__}
    for name in ("jaxlib", "equinox", "optax", "jaxlie", "mujoco", "numpy"):
        try:
            out[name] = importlib.import_module(name).__version__
        except Exception:  # noqa: BLE001 - a missing optional package is just not listed
            pass
    return out


def device() -> dict:
    import jax

    d = jax.devices()[0]
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    return {"platform": d.platform, "device_kind": d.device_kind, "cpu": cpu, "cores": os.cpu_count()}


def _run_one(name: str, quick: bool) -> list[dict]:
    module = importlib.import_module(f"benchmarks.{name}")
    records = module.run(quick=quick)
    meta = {"versions": versions(), "device": device()}
    return [{**r, **meta} for r in records]


def print_table(records: list[dict]) -> None:
    header = f"{'bench':<10} {'case':<48} {'median ms':>10} {'compile s':>10} {'peak MB':>9}  metrics"
    print(header)
    print("-" * len(header))
    for r in records:
        case = ", ".join(f"{k}={v}" for k, v in r["case"].items())
        metrics = ", ".join(
            f"{k}={v:.4g}" if isinstance(v, float) else f"{k}={v}" for k, v in r["metrics"].items()
        )
        print(
            f"{r['bench']:<10} {case[:48]:<48} {r['median_ms']:>10.2f} {r['compile_s']:>10.2f} "
            f"{r['peak_rss_mb']:>9.0f}  {metrics}"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    parser.add_argument("names", nargs="*", help=f"benchmarks to run (default all): {available()}")
    parser.add_argument("--quick", action="store_true", help="small cases only (CI smoke run)")
    parser.add_argument("--json", type=Path, help="write the records as a JSON list here")
    parser.add_argument("--_child", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)

    if args._child:  # subprocess mode: run one benchmark, dump records to the given file
        records = _run_one(args.names[0], args.quick)
        Path(args._child).write_text(json.dumps(records))
        return 0

    names = args.names or available()
    unknown = sorted(set(names) - set(available()))
    if unknown:
        parser.error(f"unknown benchmark(s) {unknown}; available: {available()}")
    records: list[dict] = []
    for name in names:
        with tempfile.TemporaryDirectory() as tmp:
            out = Path(tmp) / "records.json"
            cmd = [sys.executable, "-m", "benchmarks.run", name, "--_child", str(out)]
            if args.quick:
                cmd.append("--quick")
            proc = subprocess.run(cmd, cwd=_HERE.parent)
            if proc.returncode != 0:
                print(f"benchmark {name!r} failed (exit {proc.returncode})", file=sys.stderr)
                return proc.returncode
            records.extend(json.loads(out.read_text()))
    print_table(records)
    if args.json:
        from rsrd_jax.io import atomic_write_text

        atomic_write_text(args.json, json.dumps(records, indent=1))
        print(f"wrote {len(records)} records to {args.json}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
