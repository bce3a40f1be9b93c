"""This machine's arithmetic peaks per core and its memory bandwidths: build, run, tabulate.

Usage (needs only Python and the system's g++, not csb):

    python scripts/machine_limits.py
    python scripts/machine_limits.py --build /tmp/machine-limits --json limits.json
    python scripts/machine_limits.py --quick        # a few seconds, for tests: not the machine's limits

It compiles src/bench/machine/machine_limits.cpp with ``g++ -O2 -std=c++17 -pthread`` into --build
(a temporary directory unless given), runs it and prints two tables, each figure the median and
min-max of --reps repetitions (7 unless told):

Arithmetic, one thread (one core) unless marked "2 threads": the peak of fused multiply-adds
(12 independent chains; an FMA is 2 flops a lane) and of separate multiplies and additions (no
FMA, as csb's kernels are compiled), in GFLOP/s, for 256-bit vectors (AVX2 with FMA) and 512-bit
ones (AVX-512 F), double and float; the throughput of square roots and divisions (independent
ones, so the unit's throughput, not its latency), in lane results per ns, for scalars, 256-bit and
512-bit vectors; the core clock (a chain of dependent integer additions, 1 cycle each), in GHz.
"per cycle" divides a figure's median by that clock's max (time taken by other work only lowers a
repetition's clock): flops or lane results per cycle, roughly.

Memory: STREAM's copy (a[i] = b[i], 16 bytes an element) and triad (a[i] = b[i] + s c[i], 24 bytes
an element), the bytes counted as STREAM counts them (reads and writes, not the write-allocate
reads), on three arrays of doubles of 256 KiB (l2), 2 MiB (l3small: beyond the L2s, well inside a
32 MiB L3), 8 MiB (l3: three quarters of it) and 256 MiB (dram) each, on 1 and 2 threads (each a
contiguous half, pinned to a CPU), in GB/s (1e9 bytes per second). An L3 shared with other cores
or virtual machines may not hold all of l3; l3small is the L3's bandwidth without that.

The program's own output is plain text, one figure a line (``name median min max``, lines
``info key value`` saying what was measured); its file says how each figure is measured. --json
PATH also writes the figures, the info lines, the processor's name and the load average at the
start as JSON. The machine may be shared and noisy: run it more than once and compare.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SOURCE = ROOT / "src" / "bench" / "machine" / "machine_limits.cpp"
FLAGS = ["-O2", "-std=c++17", "-pthread"]

UNITS = {"_gflops": "GFLOP/s", "_per_ns": "1/ns", "_gbps": "GB/s", "_ghz": "GHz"}
TYPES = ("double", "float")
VECTORS = {"scalar": "scalar (SSE2)", "avx2": "256-bit (AVX2+FMA)", "avx512": "512-bit (AVX-512F)"}
LEVELS = {"l2": ("L2", "array_bytes_l2"), "l3small": ("L3", "array_bytes_l3small"), "l3": ("L3", "array_bytes_l3"),
          "dram": ("DRAM", "array_bytes_dram")}


def unit(name: str) -> str:
    return next(u for suffix, u in UNITS.items() if name.endswith(suffix))


def build(build_dir: Path) -> Path:
    cxx = shutil.which("g++")
    if cxx is None:
        raise FileNotFoundError("g++ is not on PATH")
    build_dir.mkdir(parents=True, exist_ok=True)
    exe = build_dir / "machine_limits"
    subprocess.run([cxx, *FLAGS, str(SOURCE), "-o", str(exe)], check=True)
    return exe


def parse(text: str) -> tuple[dict[str, str], dict[str, dict]]:
    """The program's output: its info lines and its figures (median, min, max, unit)."""
    info: dict[str, str] = {}
    figures: dict[str, dict] = {}
    for line in text.splitlines():
        words = line.split()
        if not words or words[0].startswith("#"):
            continue
        if words[0] == "info" and len(words) >= 3:
            info[words[1]] = " ".join(words[2:])
        elif len(words) == 4:
            median, low, high = (float(w) for w in words[1:])
            figures[words[0]] = {"median": median, "min": low, "max": high, "unit": unit(words[0])}
        else:
            raise ValueError(f"machine_limits printed a line that is neither a figure nor info: {line!r}")
    return info, figures


def processor() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown"


def compiler() -> str:
    out = subprocess.run(["g++", "--version"], capture_output=True, text=True).stdout
    return out.splitlines()[0] if out else "unknown"


def arithmetic_rows(figures: dict[str, dict]) -> list[tuple[str, str]]:
    """(label, figure name) of the arithmetic table, in order, for the figures measured."""
    rows = [("core clock (dependent integer adds)", "clock_ghz")]
    for kind, what in (("fma", "FMA peak"), ("addmul", "mul + add peak, no FMA")):
        for t in TYPES:
            for v in ("avx2", "avx512"):
                rows.append((f"{what}, {t}, {VECTORS[v]}", f"{kind}_{t}_{v}_gflops"))
    for kind, what in (("sqrt", "sqrt throughput"), ("div", "division throughput")):
        for t in TYPES:
            for v in ("scalar", "avx2", "avx512"):
                rows.append((f"{what}, {t}, {VECTORS[v]}", f"{kind}_{t}_{v}_per_ns"))
    for t in TYPES:
        for v in ("avx2", "avx512"):
            rows.append((f"FMA peak, {t}, {VECTORS[v]}, 2 threads", f"fma_{t}_{v}_2threads_gflops"))
    return [(label, name) for label, name in rows if name in figures]


def size(nbytes: int) -> str:
    return f"{nbytes >> 20} MiB" if nbytes >= 1 << 20 else f"{nbytes >> 10} KiB"


def cell(f: dict | None, digits: int = 1) -> str:
    if f is None:
        return "-"
    return f"{f['median']:.{digits}f} ({f['min']:.{digits}f}-{f['max']:.{digits}f})"


def table(info: dict[str, str], figures: dict[str, dict], meta: dict) -> str:
    quick = "; --quick: small arrays and short runs, not this machine's limits" if info.get("quick") == "1" else ""
    lines = [f"{meta['processor']}, {info.get('cpus_allowed', '?')} CPUs allowed; {meta['compiler']} "
             f"{' '.join(FLAGS)}; load average at the start {meta['load_average'][0]:.2f}; "
             f"{info.get('reps', '?')} repetitions, median (min-max){quick}"]
    clock = figures.get("clock_ghz", {}).get("max")  # what the noise (time taken by others) only lowers
    lines.append("")
    lines.append(f"{'arithmetic, 1 thread (1 core) unless marked':<58} {'unit':>8} {'median (min-max)':>24} "
                 f"{'per cycle':>9}")
    for label, name in arithmetic_rows(figures):
        f = figures[name]
        digits = 1 if f["median"] >= 10 else 3
        per_cycle = "-" if name == "clock_ghz" or not clock else f"{f['median'] / clock:.2f}"
        lines.append(f"{label:<58} {f['unit']:>8} {cell(f, digits):>24} {per_cycle:>9}")
    lines.append("")
    lines.append(f"memory: STREAM kernels on 3 arrays of doubles, bytes as STREAM counts them "
                 f"({info.get('stream_vectors', '?')} vectors, ordinary stores)")
    lines.append(f"{'working set':<28} {'kernel':<7} {'1 thread GB/s':>24} {'2 threads GB/s':>24}")
    for level, (name, key) in LEVELS.items():
        where = f"{name} ({level}): 3 x {size(int(info.get(key, 0)))}"
        for kernel in ("copy", "triad"):
            one = figures.get(f"{kernel}_{level}_1thread_gbps")
            two = figures.get(f"{kernel}_{level}_2threads_gbps")
            if one is None and two is None:
                continue
            lines.append(f"{where:<28} {kernel:<7} {cell(one):>24} {cell(two):>24}")
    lines.append("")
    lines.append("FMA and mul + add: flops per second (an FMA is 2 flops a lane); sqrt and division: lane results "
                 "per ns; per cycle: the median over the core clock's max; 2 threads: the sum over both")
    return "\n".join(lines)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--build", type=Path, help="directory for the program (a temporary one if not given)")
    p.add_argument("--json", type=Path, help="also write the figures to this JSON file")
    p.add_argument("--quick", action="store_true", help="small arrays, 3 short repetitions (for tests)")
    p.add_argument("--reps", type=int, help="repetitions of each figure (7 unless --quick)")
    args = p.parse_args()

    if shutil.which("g++") is None:
        print("machine_limits: g++ is not on PATH; it is needed to build the program", file=sys.stderr)
        return 2
    load = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        exe = build(args.build if args.build is not None else Path(tmp))
        cmd = [str(exe)] + (["--quick"] if args.quick else []) + (["--reps", str(args.reps)] if args.reps else [])
        out = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
    info, figures = parse(out)
    meta = {"processor": processor(), "compiler": compiler(), "flags": FLAGS, "load_average": list(load)}
    bad = [name for name, f in figures.items()
           if not all(math.isfinite(f[k]) and f[k] > 0 for k in ("median", "min", "max"))]
    print(table(info, figures, meta))
    if args.json is not None:
        args.json.write_text(json.dumps({**meta, "info": info, "figures": figures}, indent=2) + "\n")
    if bad:
        print(f"machine_limits: figures not finite and positive: {', '.join(bad)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
