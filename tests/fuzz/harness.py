"""csb's fuzzing harness: mutated files through every loader and the scene parser.

csb promises that a file it cannot use gives a clear error naming the file, never a crash, a hang,
unbounded memory, a stray print or an exception of another type. This harness checks the promise
on files mutated from a seed corpus (``tests/fuzz/seeds``: the formats the tests write), with a
mutation loop of its own: byte flips, interesting integers in binary fields, numbers replaced by
extremes in text, lines duplicated, dropped or swapped, ranges cut, repeated or spliced from
another seed, the extension dropped. Each case is read in a worker process, so a crash or a hang
costs that worker only and is recorded against the case that caused it.

Targets: ``mesh`` (:func:`csb.load_mesh`: Assimp and csb's OBJ/OFF/PLY/STL checks), ``tet_mesh``
(:func:`csb.load_tet_mesh`: meshio) and ``scene`` (:func:`csb.load_scene` and ``Scene.build``,
which reads the meshes a scene names and builds the model).

Outcomes of a case:

  result     the loader returned
  error      a ``csb.Error`` (MeshError, SceneError, ParameterError, ...) or FileNotFoundError
  ---- findings: each is a defect ----
  exception  any other exception type (TypeError, KeyError, a bare RuntimeError, ...)
  crash      the worker died (a signal, or an exit the loader caused)
  hang       no answer within the case's time limit (the loader's own limit plus a margin)
  memory     a MemoryError, or the worker's peak memory past ``--worker-memory``
  noise      the case printed to the terminal (meshio's and Assimp's prints must not reach it)

Usage (from the project's root, with csb installed)::

  python tests/fuzz/harness.py --minutes 60             # the long run; ./dev fuzz runs this
  python tests/fuzz/harness.py --cases 200 --seed 3     # a fixed number of cases per target
  python tests/fuzz/harness.py --replay FILE...         # one outcome line per file
  python tests/fuzz/harness.py --write-seeds            # regenerate tests/fuzz/seeds

Cases are deterministic: case ``k`` of a target under ``--seed s`` is the same file on every run.
Findings are written to ``<out>/findings/<target>/`` with a ``.txt`` giving the outcome and the
message; a finding, once understood and fixed, is moved to ``tests/fuzz/regressions/<target>/``,
where ``tests/fuzz/test_fuzz.py`` replays it on every test run.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import random
import select
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

HERE = Path(__file__).resolve().parent
SEEDS = HERE / "seeds"
REGRESSIONS = HERE / "regressions"
TARGETS = ("mesh", "tet_mesh", "scene")
ACCEPTED = ("result", "error")
FINDINGS = ("exception", "crash", "hang", "memory", "noise")

# The loaders' own time limits in the worker (s): a file a reader loops on gives csb's MeshError
# after this long, which is an accepted outcome. The harness calls a case hung only if the worker
# has not answered HANG_MARGIN seconds after that (a scene may read two files).
LOADER_TIMEOUT = {"mesh": 5.0, "tet_mesh": 15.0, "scene": 0.0}
CASE_LIMIT = {"mesh": 5.0 + 20.0, "tet_mesh": 15.0 + 20.0, "scene": 2 * 60.0 + 40.0}
WORKER_MEMORY = 1.5 * 1024**3  # bytes of peak resident memory; the loaders' children have their own limits


# ---------------------------------------------------------------------------------------------
# The worker: reads one case per line on stdin, answers one JSON line per case.

def _run_case(target: str, path: str) -> tuple[str, str, str]:
    import csb

    try:
        if target == "mesh":
            csb.load_mesh(path, timeout=LOADER_TIMEOUT["mesh"])
        elif target == "tet_mesh":
            csb.load_tet_mesh(path, timeout=LOADER_TIMEOUT["tet_mesh"])
        else:
            csb.load_scene(path).build()
        return "result", "", ""
    except (csb.Error, FileNotFoundError) as e:
        return "error", type(e).__name__, str(e)
    except MemoryError as e:
        return "memory", type(e).__name__, str(e)
    except Exception as e:  # noqa: BLE001 - any other type is what the harness looks for
        return "exception", type(e).__name__, str(e)


def worker() -> None:
    import resource
    import warnings

    # Replies go to the original stdout; fds 1 and 2 go to a file, so that anything a loader
    # prints (from Python or from C) is seen and charged to the case that printed it.
    reply = os.fdopen(os.dup(1), "w", buffering=1)
    sink = tempfile.TemporaryFile()
    sys.stdout.flush()
    sys.stderr.flush()
    os.dup2(sink.fileno(), 1)
    os.dup2(sink.fileno(), 2)
    warnings.simplefilter("ignore")  # MeshWarning and friends are answers, not noise
    import csb  # noqa: F401 - imported before the first case so its start-up is not charged to it

    for line in sys.stdin:
        case = json.loads(line)
        before = os.fstat(sink.fileno()).st_size
        t0 = time.perf_counter()
        outcome, kind, message = _run_case(case["target"], case["path"])
        seconds = time.perf_counter() - t0
        sys.stdout.flush()
        sys.stderr.flush()
        printed = os.fstat(sink.fileno()).st_size - before
        if printed and outcome in ACCEPTED:
            sink.seek(before)
            outcome, message = "noise", sink.read(min(printed, 400)).decode("utf-8", "replace")
            sink.seek(0, os.SEEK_END)
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        reply.write(json.dumps(dict(outcome=outcome, kind=kind, message=message[:1000], seconds=seconds,
                                    peak=peak)) + "\n")


# ---------------------------------------------------------------------------------------------
# The driver: keeps a worker, feeds it cases, watches its time and memory.

@dataclass
class Outcome:
    outcome: str
    kind: str = ""
    message: str = ""
    seconds: float = 0.0


class Worker:
    def __init__(self, memory: float = WORKER_MEMORY):
        self.memory = memory
        self.proc: subprocess.Popen | None = None

    def _start(self) -> subprocess.Popen:
        env = dict(os.environ, PYTHONUNBUFFERED="1")
        return subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--worker"], stdin=subprocess.PIPE,
                                stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, env=env, text=True, bufsize=1)

    def stop(self) -> None:
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            for pipe in (self.proc.stdin, self.proc.stdout):
                try:
                    pipe.close()
                except OSError:  # a broken pipe to a dead worker
                    pass
            self.proc = None

    def run(self, target: str, path: str) -> Outcome:
        if self.proc is None:
            self.proc = self._start()
        proc = self.proc
        t0 = time.perf_counter()
        try:
            proc.stdin.write(json.dumps(dict(target=target, path=path)) + "\n")
            proc.stdin.flush()
        except BrokenPipeError:
            self.stop()
            return Outcome("crash", "", "the worker had exited before the case was sent")
        ready, _, _ = select.select([proc.stdout], [], [], CASE_LIMIT[target] + 30.0)  # + the worker's start-up
        if not ready:
            self.stop()
            return Outcome("hang", "", f"no answer after {time.perf_counter() - t0:.0f} s", time.perf_counter() - t0)
        line = proc.stdout.readline()
        if not line:
            code = proc.wait()
            self.stop()
            how = f"signal {-code}" if code < 0 else f"exit status {code}"
            return Outcome("crash", "", f"the worker died ({how})", time.perf_counter() - t0)
        answer = json.loads(line)
        out = Outcome(answer["outcome"], answer["kind"], answer["message"], answer["seconds"])
        if out.seconds > CASE_LIMIT[target]:
            out = Outcome("hang", out.kind, f"took {out.seconds:.1f} s (limit {CASE_LIMIT[target]:.0f} s): {out.message}",
                          out.seconds)
        if answer["peak"] > self.memory:
            out = Outcome("memory", out.kind, f"worker peak {answer['peak'] / 1e9:.2f} GB: {out.message}", out.seconds)
            self.stop()  # its peak stays high: start a fresh one
        elif out.outcome in FINDINGS:
            self.stop()  # after a finding, start clean
        return out


# ---------------------------------------------------------------------------------------------
# Mutations.

INTERESTING_NUMBERS = [b"0", b"-1", b"1", b"-0", b"2147483647", b"2147483648", b"4294967295", b"4294967296",
                       b"9223372036854775807", b"18446744073709551616", b"99999999999999999999999", b"1e308",
                       b"-1e308", b"1e-320", b"nan", b"inf", b"-inf", b"1e999", b"0x10", b"", b"1.5", b"3"]
INTERESTING_INTS = [0, 1, 2, 3, 0x7F, 0x80, 0xFF, 0x7FFF, 0x8000, 0xFFFF, 0x7FFFFFFF, 0x80000000, 0xFFFFFFFF,
                    0x10000, 0x100000, 0x40000000]


def _numbers(data: bytes) -> list[tuple[int, int]]:
    """Spans of decimal numbers in text."""
    spans, i, n = [], 0, len(data)
    while i < n:
        if data[i:i + 1].isdigit() or (data[i:i + 1] in (b"-", b".") and data[i + 1:i + 2].isdigit()):
            j = i + 1
            while j < n and (data[j:j + 1].isdigit() or data[j:j + 1] in b".eE+-"):
                j += 1
            spans.append((i, j))
            i = j
        else:
            i += 1
    return spans


def _mutate_once(b: bytearray, rng: random.Random, others: list[bytes]) -> bytearray:
    n = len(b)
    if n == 0:
        return bytearray(rng.randbytes(rng.randint(1, 64)))
    kind = rng.randrange(11)
    if kind == 0:  # flip bits
        for _ in range(rng.randint(1, 8)):
            b[rng.randrange(n)] ^= 1 << rng.randrange(8)
    elif kind == 1:  # set bytes
        for _ in range(rng.randint(1, 8)):
            b[rng.randrange(n)] = rng.choice([0, 0xFF, 0x7F, 0x80, 0x0A, 0x20, rng.randrange(256)])
    elif kind == 2:  # an interesting integer in a binary field
        width = rng.choice([1, 2, 4, 4, 8])
        if n >= width:
            at = rng.randrange(n - width + 1) & ~(width - 1) if rng.random() < 0.7 else rng.randrange(n - width + 1)
            v = rng.choice(INTERESTING_INTS) + rng.choice([0, 0, 1, -1])
            b[at:at + width] = (v % (1 << (8 * width))).to_bytes(width, rng.choice(["little", "big"]))
    elif kind == 3:  # a number in text replaced by an extreme
        spans = _numbers(bytes(b[:200_000]))
        if spans:
            i, j = rng.choice(spans)
            b[i:j] = rng.choice(INTERESTING_NUMBERS)
    elif kind in (4, 5):  # lines dropped, duplicated or swapped
        lines = bytes(b).split(b"\n")
        if len(lines) > 1:
            i, j = rng.randrange(len(lines)), rng.randrange(len(lines))
            what = rng.randrange(3)
            if what == 0:
                del lines[i]
            elif what == 1:
                lines.insert(i, lines[j])
            else:
                lines[i], lines[j] = lines[j], lines[i]
            b = bytearray(b"\n".join(lines))
    elif kind == 6:  # truncate
        b = b[: rng.randrange(n)]
    elif kind == 7:  # cut a range
        i = rng.randrange(n)
        del b[i: i + rng.randint(1, max(1, n // 8))]
    elif kind == 8:  # repeat a range
        i = rng.randrange(n)
        chunk = b[i: i + rng.randint(1, 256)]
        b[i:i] = chunk * rng.randint(1, 64)
    elif kind == 9:  # splice from another seed of the same target
        other = rng.choice(others)
        if other:
            i, j = rng.randrange(n), rng.randrange(len(other))
            b = b[:i] + bytearray(other[j: j + rng.randint(1, 512)]) + b[i + rng.randint(0, 64):]
    else:  # insert random or interesting bytes
        i = rng.randrange(n + 1)
        b[i:i] = rng.choice([rng.randbytes(rng.randint(1, 16)), b"\x00", b"\xff\xfe", b"\r", b"\n\n", b"#", b"\\",
                             b"\xef\xbb\xbf", b"{", b"}", b"[", b"]", b"\"", b"=", b"<", b"/>"])
    return b


def mutate(data: bytes, rng: random.Random, others: list[bytes]) -> bytes:
    b = bytearray(data)
    for _ in range(rng.choice([1, 1, 1, 2, 2, 3, 4, 8])):
        b = _mutate_once(b, rng, others)
    return bytes(b[: 4 * 1024 * 1024])


# ---------------------------------------------------------------------------------------------
# Seeds and cases.

def seeds(target: str) -> list[Path]:
    folder = SEEDS / target
    files = sorted(p for p in folder.iterdir() if p.is_file() and not p.name.startswith("."))
    if target == "scene":
        files = [p for p in files if p.suffix == ".toml"]
    return [p for p in files if p.suffix != ".bin"]  # a glTF's buffer is read with it, not alone


@dataclass
class Case:
    target: str
    index: int
    seed_file: Path
    data: bytes
    suffix: str

    @property
    def digest(self) -> str:
        return hashlib.sha1(self.data).hexdigest()[:16]


@dataclass
class Corpus:
    target: str
    files: list[Path]
    data: list[bytes] = field(init=False)

    def __post_init__(self) -> None:
        self.data = [p.read_bytes() for p in self.files]

    def case(self, seed: int, index: int) -> Case:
        rng = random.Random(f"{seed}:{self.target}:{index}")
        k = rng.randrange(len(self.files))
        data = mutate(self.data[k], rng, self.data)
        suffix = self.files[k].suffix
        if self.target == "mesh" and rng.random() < 0.05:
            suffix = ""  # read by content
        return Case(self.target, index, self.files[k], data, suffix)


def materialise(case: Case, folder: Path) -> Path:
    """Write the case's file, beside the seed files it may name (a glTF's buffer, a scene's meshes)."""
    path = folder / f"case{case.suffix}"
    path.write_bytes(case.data)
    return path


def prepare_folder(target: str, root: Path) -> Path:
    folder = root / target
    folder.mkdir(parents=True, exist_ok=True)
    companions = [p for p in (SEEDS / target).iterdir() if p.suffix in {"mesh": (".bin",), "scene": (".obj", ".msh")}.get(target, ())]
    if target == "scene":  # the bundled cloth_drop names the bundled cloth mesh
        import csb

        companions.append(Path(csb.__file__).parent / "scenes" / "meshes")
    for p in companions:
        link = folder / p.name
        if not link.exists():
            link.symlink_to(p)
    return folder


def save_finding(case: Case, out: Outcome, root: Path) -> Path:
    folder = root / "findings" / case.target
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{out.outcome}-{case.digest}{case.suffix}"
    path.write_bytes(case.data)
    path.with_name(path.name + ".txt").write_text(
        f"outcome: {out.outcome}\ntype: {out.kind}\nseed file: {case.seed_file.name}\ncase: {case.index}\n"
        f"seconds: {out.seconds:.2f}\nmessage: {out.message}\n")
    return path


@dataclass
class Tally:
    cases: int = 0
    seconds: float = 0.0
    outcomes: dict[str, int] = field(default_factory=dict)

    def add(self, out: Outcome, seconds: float) -> None:
        self.cases += 1
        self.seconds += seconds
        self.outcomes[out.outcome] = self.outcomes.get(out.outcome, 0) + 1


def fuzz(targets: list[str], *, seed: int = 0, cases: int | None = None, minutes: float | None = None,
         out_dir: Path | None = None, progress: bool = True, start: int = 0) -> tuple[dict[str, Tally], list[Path]]:
    """Run the mutation loop over the targets: `cases` cases each, or `minutes` in all shared equally
    between the targets (a tet mesh costs a child process with meshio, a scene microseconds)."""
    root = Path(out_dir) if out_dir is not None else Path("out/fuzz")
    work = Path(tempfile.mkdtemp(prefix="csb-fuzz-cases-"))
    corpora = {t: Corpus(t, seeds(t)) for t in targets}
    folders = {t: prepare_folder(t, work) for t in targets}
    tallies = {t: Tally() for t in targets}
    found: list[Path] = []
    worker = Worker()
    t_end = time.monotonic() + 60.0 * minutes if minutes else None
    last_report = time.monotonic()
    index = {t: start for t in targets}
    try:
        while True:
            if cases is not None:  # a fixed number per target, round-robin
                left = [t for t in targets if index[t] - start < cases]
                if not left:
                    break
                t = left[0]
            else:  # equal time per target: the one that has had the least goes next
                if time.monotonic() >= t_end:
                    break
                t = min(targets, key=lambda x: tallies[x].seconds)
            case = corpora[t].case(seed, index[t])
            index[t] += 1
            path = materialise(case, folders[t])
            t0 = time.perf_counter()
            out = worker.run(t, str(path))
            tallies[t].add(out, time.perf_counter() - t0)
            if out.outcome in FINDINGS:
                saved = save_finding(case, out, root)
                found.append(saved)
                if progress:
                    print(f"finding: {t} case {case.index} ({case.seed_file.name}): {out.outcome} {out.kind}: "
                          f"{out.message[:200]!r} -> {saved}", flush=True)
            if progress and time.monotonic() - last_report > 60.0:
                last_report = time.monotonic()
                print(summary(tallies), flush=True)
    finally:
        worker.stop()
        shutil.rmtree(work, ignore_errors=True)
    return tallies, found


def summary(tallies: dict[str, Tally]) -> str:
    rows = []
    for t, s in tallies.items():
        kinds = ", ".join(f"{k} {v}" for k, v in sorted(s.outcomes.items()))
        rate = s.cases / s.seconds if s.seconds else 0.0
        rows.append(f"  {t:9s} {s.cases:7d} cases  {rate:6.1f} cases/s  {kinds}")
    return "\n".join(rows)


def replay(paths: list[Path]) -> list[tuple[Path, Outcome]]:
    """Each file through its target's loader (the target is the name of the folder holding it)."""
    worker = Worker()
    results = []
    work = Path(tempfile.mkdtemp(prefix="csb-fuzz-replay-"))
    try:
        folder = prepare_folder("scene", work)  # a scene is read beside the seed meshes it names
        for p in paths:
            target = p.parent.name
            if target not in TARGETS:
                raise SystemExit(f"{p}: put the file in a folder named after its target ({', '.join(TARGETS)})")
            if target == "scene":
                shutil.copy(p, folder / p.name)
                p_run = folder / p.name
            else:
                p_run = p
            results.append((p, worker.run(target, str(p_run))))
    finally:
        worker.stop()
        shutil.rmtree(work, ignore_errors=True)
    return results


# ---------------------------------------------------------------------------------------------
# The seed corpus, written by csb's and meshio's writers (the formats the tests use).

def write_seeds() -> None:
    import meshio
    import numpy as np

    import csb

    for t in TARGETS:
        (SEEDS / t).mkdir(parents=True, exist_ok=True)
    cloth = csb.cloth_grid(1.2, 0.8, 4, 3, plane="xy")
    v, tri = np.asarray(cloth.vertices), np.asarray(cloth.triangles)
    m = SEEDS / "mesh"
    surface = meshio.Mesh(v, [("triangle", tri)])
    meshio.write(m / "cloth.obj", surface)
    meshio.write(m / "cloth.off", surface)
    meshio.write(m / "cloth_ascii.ply", surface, binary=False)
    meshio.write(m / "cloth_binary.ply", surface, binary=True)
    meshio.write(m / "cloth_ascii.stl", surface, binary=False)
    meshio.write(m / "cloth_binary.stl", surface, binary=True)
    for ext in ("gltf", "glb", "dae", "3ds", "fbx", "x3d"):
        try:
            csb.save_mesh(cloth, str(m / f"cloth.{ext}"))
        except csb.Error:
            pass  # not every Assimp build writes every format
    (m / "quads_negative.obj").write_text(
        "# quads, negative indices, normals and texture coordinates\n"
        "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0\nv 2 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\n"
        "g panel\nf 1/1/1 2/2/1 3/3/1 4/1/1\nf -4 5 6 -3\n")
    (m / "quads.off").write_text("OFF\n# a unit square as one quad and a triangle\n5 2 0\n"
                                 "0 0 0\n1 0 0\n1 1 0\n0 1 0\n2 0 0\n4 0 1 2 3\n3 1 4 2\n")
    tets = csb.tet_box((0.2, 0.1, 0.1), (2, 1, 1))
    body = meshio.Mesh(np.asarray(tets.points), [("tetra", np.asarray(tets.tets))])
    tm = SEEDS / "tet_mesh"
    meshio.write(tm / "box_22.msh", body, file_format="gmsh22", binary=False)
    meshio.write(tm / "box_41_ascii.msh", body, file_format="gmsh", binary=False)
    meshio.write(tm / "box_41_binary.msh", body, file_format="gmsh", binary=True)
    meshio.write(tm / "box_ascii.vtu", body, binary=False)
    meshio.write(tm / "box_binary.vtu", body, binary=True)
    meshio.write(tm / "box_ascii.vtk", body, binary=False)
    meshio.write(tm / "box_binary.vtk", body, binary=True)
    meshio.write(tm / "box.mesh", body)
    meshio.write(tm / "box.inp", body)
    sc = SEEDS / "scene"
    meshio.write(sc / "cloth.obj", surface)
    meshio.write(sc / "body.msh", body, file_format="gmsh22", binary=False)
    scenes = Path(csb.__file__).parent / "scenes"
    for p in sorted(scenes.glob("*.toml")):
        text = p.read_text()
        # small models, so that a case costs milliseconds, not the bundled scenes' seconds
        for n in (25, 30, 32):
            text = text.replace(f"resolution = [{n}, {n}]", "resolution = [6, 6]")
        (sc / p.name).write_text(text)
    (sc / "cloth_file.toml").write_text(
        '[scene]\nname = "cloth_file"\nduration = 0.1\n\n[solver]\nmethod = "pbd"\ndt = 0.01\nsubsteps = 2\n'
        'iterations = 4\n\n[[mesh]]\nname = "cloth"\nfile = "cloth.obj"\nscale = 0.5\nrotate = [0.1, 0.0, 0.0]\n'
        'density = 0.2\nstretch = { stiffness = 0.9 }\nbending = { stiffness = 0.1, compliance = 0.5 }\npin = { indices = [0, 3] }\nself_collision = { thickness = 0.01 }\n\n'
        '[[collider]]\ntype = "sphere"\ncenter = [0.0, -1.0, 0.0]\nradius = 0.3\n')
    (sc / "tet_file.toml").write_text(
        '[scene]\nname = "tet_file"\nduration = 0.1\n\n[solver]\nmethod = "xpbd"\ndt = 0.01\nsubsteps = 2\n'
        'iterations = 2\n\n[[mesh]]\nname = "body"\nfile = "body.msh"\nkind = "volume"\ndensity = 100.0\n'
        'stretch = { compliance = 1e-6 }\nvolume = { compliance = 1e-6 }\npin = { near = [[-0.1, 0.05, 0.05]], max_distance = 0.01 }\n')


# ---------------------------------------------------------------------------------------------

def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    ap.add_argument("--minutes", type=float, help="run for this long in all (an equal share of time per target)")
    ap.add_argument("--cases", type=int, help="run this many cases per target")
    ap.add_argument("--seed", type=int, default=0, help="the run's seed (cases are deterministic in it)")
    ap.add_argument("--start", type=int, default=0, help="the first case index")
    ap.add_argument("--targets", default=",".join(TARGETS), help=f"comma-separated, of {', '.join(TARGETS)}")
    ap.add_argument("--out", type=Path, default=Path("out/fuzz"), help="findings go to OUT/findings/<target>/")
    ap.add_argument("--replay", nargs="+", type=Path, metavar="FILE")
    ap.add_argument("--write-seeds", action="store_true")
    a = ap.parse_args(argv)
    if a.worker:
        worker()
        return 0
    if a.write_seeds:
        write_seeds()
        return 0
    if a.replay:
        bad = 0
        for p, out in replay(a.replay):
            print(f"{p}: {out.outcome} {out.kind} {out.message[:300]!r}")
            bad += out.outcome not in ACCEPTED
        return 1 if bad else 0
    targets = [t for t in a.targets.split(",") if t]
    unknown = set(targets) - set(TARGETS)
    if unknown:
        ap.error(f"unknown targets {sorted(unknown)}; choose from {', '.join(TARGETS)}")
    if a.minutes is None and a.cases is None:
        ap.error("give --minutes or --cases")
    t0 = time.monotonic()
    tallies, found = fuzz(targets, seed=a.seed, cases=a.cases, minutes=a.minutes, out_dir=a.out, start=a.start)
    wall = time.monotonic() - t0
    total = sum(s.cases for s in tallies.values())
    print(f"fuzzing: {total} cases in {wall / 60:.1f} min ({total / wall:.1f} cases/s), seed {a.seed}, "
          f"from case {a.start}")
    print(summary(tallies))
    print(f"findings: {len(found)}" + (f" (in {a.out / 'findings'})" if found else ""))
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
