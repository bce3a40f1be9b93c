"""The reading process of :func:`csb.load_tet_mesh`: meshio runs here, in a child process, under a
memory limit, so that a file on which meshio would exhaust memory, call ``sys.exit`` or print to
the terminal costs only this process.

Run as a script by path (``python -I _meshio_child.py SEARCH_PATH FILE OUT_DIR MAX_MEMORY``), so
that it does not import csb. It writes ``OUT_DIR/result.json`` and, on success,
``points.npy`` (float64, N x 3) and ``tets.npy`` (int64, M x 4). Its stdout and stderr go to a
file of the parent's, never to the user's terminal.
"""

import json
import os
import sys


def _address_space() -> int:
    """Bytes of address space this process has mapped now (0 where /proc is absent)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def _limit_memory(max_memory: int) -> None:
    """Cap the address space at what Python, numpy and meshio already use plus ``max_memory``."""
    try:
        import resource
    except ImportError:  # not POSIX: no limit available, the deadline still applies
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    limit = _address_space() + max_memory
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))


def _read(name: str, out: str) -> dict:
    import numpy as np

    m = __import__("meshio").read(name)
    points = np.asarray(m.points, dtype=np.float64)
    blocks, tetra10, found = [], 0, []
    for block in m.cells:
        data = np.asarray(block.data)
        found.append(f"{block.type} x {len(data)}")
        if block.type == "tetra":
            blocks.append(data.astype(np.int64))
        elif block.type == "tetra10":
            tetra10 += len(data)
            blocks.append(data[:, :4].astype(np.int64))
    tets = np.concatenate(blocks) if blocks else np.zeros((0, 4), dtype=np.int64)
    np.save(os.path.join(out, "points.npy"), points, allow_pickle=False)
    np.save(os.path.join(out, "tets.npy"), tets, allow_pickle=False)
    return {"status": "ok", "tetra10": tetra10, "found": found}


def main(argv: list[str]) -> int:
    search_path, name, out, max_memory = json.loads(argv[1]), argv[2], argv[3], int(argv[4])
    sys.path[:] = search_path
    sys.stdout.reconfigure(line_buffering=True)  # meshio's prints and its stderr messages in the order made
    try:
        import meshio  # noqa: F401  (imported before the limit: the limit bounds the reading only)
        import numpy  # noqa: F401
    except ImportError as e:
        result = {"status": "error", "error": f"meshio is not available: {e}"}
    else:
        _limit_memory(max_memory)
        try:
            result = _read(name, out)
        except MemoryError:
            result = {"status": "memory"}
        except SystemExit:  # meshio exits (after printing why) when no reader accepts the file
            result = {"status": "error", "error": "meshio could not read it as a mesh"}
        except BaseException as e:  # meshio raises many types (ReadError, ValueError, KeyError, ...)
            result = {"status": "error", "error": f"meshio could not read it as a mesh: {type(e).__name__}: {e}"}
    try:
        with open(os.path.join(out, "result.json"), "w") as f:
            json.dump(result, f)
    except MemoryError:
        return 3
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
