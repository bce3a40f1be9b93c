"""Reading a scene file: its text, to find the line of a key, and typed getters that raise a
SceneError naming the file, the line and the key. The scene schema itself is in csb.scene."""

from __future__ import annotations

import math
import re
import sys
import tomllib
from pathlib import Path
from typing import Any, Callable, Sequence

from . import _core

__all__ = ["SceneError", "read_toml"]

Vec3 = tuple[float, float, float]


class SceneError(_core.Error, ValueError):
    """A scene file that cannot be used; the message names the file, the key and the line."""


_MISSING = object()


class _Source:
    """The scene file's text, to find the line of a key for error messages."""

    _header = re.compile(r"^\s*(\[\[?)\s*([A-Za-z0-9_.\-\s]+?)\s*(\]\]?)\s*(#.*)?$")

    def __init__(self, path: Path, text: str):
        self.path = path
        self.lines = text.splitlines()

    def line_of(self, table: tuple[Any, ...], key: str | None) -> int | None:
        """1-based line of ``key`` inside ``table`` (e.g. ("mesh", 0, "stretch")), or of the table."""
        start, end = self._region(table)
        if start is None:
            return None
        if key is None:
            return start + 1
        pattern = re.compile(r"(^|[\s{,])" + re.escape(key) + r"\s*=")
        for i in range(start, end):
            if pattern.search(self.lines[i].split("#", 1)[0]):
                return i + 1
        return start + 1

    def _region(self, table: tuple[Any, ...]) -> tuple[int | None, int]:
        names = [t for t in table if isinstance(t, str)]
        if not names:
            return 0, len(self.lines)
        # Find the header of the outermost table (counting [[array]] occurrences), then narrow to
        # a [sub.table] header or an inline `sub = {` line inside it.
        top, index = names[0], next((t for t in table if isinstance(t, int)), 0)
        seen, start = -1, None
        for i, line in enumerate(self.lines):
            m = self._header.match(line)
            if m and m.group(2).replace(" ", "") == top:
                seen += 1
                if seen == index:
                    start = i
                    break
        if start is None:
            return None, 0
        end = len(self.lines)
        for i in range(start + 1, len(self.lines)):
            m = self._header.match(self.lines[i])
            if m and not m.group(2).replace(" ", "").startswith(top + "."):
                end = i
                break
        for sub in names[1:]:
            full = ".".join(names[: names.index(sub) + 1])
            inline = re.compile(r"(^|[\s{,])" + re.escape(sub) + r"\s*=")
            for i in range(start, end):
                m = self._header.match(self.lines[i])
                if (m and m.group(2).replace(" ", "") == full) or inline.search(self.lines[i].split("#", 1)[0]):
                    start = i
                    break
        return start, end


class _Table:
    """A TOML table being read: typed getters that raise SceneError naming file, key and line."""

    def __init__(self, source: _Source, data: dict[str, Any], path: tuple[Any, ...], label: str):
        self.source, self.data, self.path, self.label = source, data, path, label
        self.used: set[str] = set()

    def error(self, key: str | None, message: str) -> SceneError:
        line = self.source.line_of(self.path, key)
        where = f"{self.source.path}:{line}" if line else f"{self.source.path}"
        name = f"{self.label}.{key}" if key else self.label
        return SceneError(f"{where}: {name}: {message}")

    def has(self, key: str) -> bool:
        return key in self.data

    def raw(self, key: str, default: Any = _MISSING) -> Any:
        self.used.add(key)
        if key not in self.data:
            if default is _MISSING:
                raise self.error(None, f"missing key '{key}'")
            return default
        return self.data[key]

    def number(self, key: str, default: Any = _MISSING, *, check: Callable[[float], bool] | None = None,
               expect: str = "a number", allow_inf: bool = False) -> float:
        v = self.raw(key, default)
        if v is default and default is not _MISSING:
            return v
        if allow_inf and isinstance(v, float) and v == math.inf:
            return v
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
            raise self.error(key, f"must be {expect}, got {v!r}")
        if check is not None and not check(float(v)):
            raise self.error(key, f"must be {expect}, got {v!r}")
        return float(v)

    def integer(self, key: str, default: Any = _MISSING, *, minimum: int | None = None,
                maximum: int = _core.MAX_INDEX) -> int:
        """An integer in [minimum, maximum]; the default maximum is the largest index or count the
        C++ side holds (32 bits), since every integer of a scene ends up in a binding."""
        v = self.raw(key, default)
        if v is default and default is not _MISSING:
            return v
        expect = f"an integer in [{minimum}, {maximum}]" if minimum is not None else f"an integer <= {maximum}"
        if (isinstance(v, bool) or not isinstance(v, int) or (minimum is not None and v < minimum)
                or v > maximum):
            raise self.error(key, f"must be {expect}, got {v!r}")
        return v

    def boolean(self, key: str, default: Any = _MISSING) -> bool:
        v = self.raw(key, default)
        if not isinstance(v, bool):
            raise self.error(key, f"must be true or false, got {v!r}")
        return v

    def string(self, key: str, default: Any = _MISSING, *, choices: Sequence[str] | None = None) -> str:
        v = self.raw(key, default)
        if v is default and default is not _MISSING:
            return v
        if not isinstance(v, str):
            raise self.error(key, f"must be a string, got {v!r}")
        if choices is not None and v not in choices:
            raise self.error(key, f"must be one of {', '.join(repr(c) for c in choices)}, got {v!r}")
        return v

    def vector(self, key: str, default: Any = _MISSING, *, size: int = 3) -> tuple[float, ...]:
        v = self.raw(key, default)
        if v is default and default is not _MISSING:
            return v
        if (not isinstance(v, list) or len(v) != size
                or any(isinstance(x, bool) or not isinstance(x, (int, float)) or not math.isfinite(x) for x in v)):
            raise self.error(key, f"must be a list of {size} finite numbers, got {v!r}")
        return tuple(float(x) for x in v)

    def vectors(self, key: str, default: Any = _MISSING) -> tuple[Vec3, ...]:
        v = self.raw(key, default)
        if v is default and default is not _MISSING:
            return v
        if not isinstance(v, list) or not all(
            isinstance(p, list) and len(p) == 3
            and all(not isinstance(x, bool) and isinstance(x, (int, float)) and math.isfinite(x) for x in p)
            for p in v
        ):
            raise self.error(key, f"must be a list of [x, y, z] points (m), got {v!r}")
        return tuple((float(p[0]), float(p[1]), float(p[2])) for p in v)

    def integers(self, key: str, default: Any = _MISSING) -> tuple[int, ...]:
        v = self.raw(key, default)
        if v is default and default is not _MISSING:
            return v
        if not isinstance(v, list) or not all(isinstance(x, int) and not isinstance(x, bool) for x in v):
            raise self.error(key, f"must be a list of integers, got {v!r}")
        if any(not 0 <= x <= _core.MAX_INDEX for x in v):
            raise self.error(key, f"must be a list of integers in [0, {_core.MAX_INDEX}], got {v!r}")
        return tuple(v)

    def scale(self, key: str = "scale") -> tuple[float, float, float]:
        """A uniform factor or one per axis, non-zero (default 1)."""
        if isinstance(self.raw(key, 1.0), list):
            return self.vector(key)
        s = self.number(key, 1.0, check=lambda x: x != 0, expect="a non-zero factor")
        return (s, s, s)

    def table(self, key: str, label: str | None = None) -> "_Table | None":
        v = self.raw(key, None)
        if v is None:
            return None
        if not isinstance(v, dict):
            raise self.error(key, f"must be a table, got {v!r}")
        return _Table(self.source, v, self.path + (key,), label or f"{self.label}.{key}")

    def finish(self) -> None:
        """Unknown keys are errors: a misspelt key must not be silently ignored."""
        for key in self.data:
            if key not in self.used:
                allowed = ", ".join(sorted(self.used))
                raise self.error(key, f"unknown key; expected one of: {allowed}")


def read_toml(p: Path, what: str, error: type[SceneError] = SceneError) -> tuple[dict[str, Any], _Source]:
    """A TOML file's tables and its text (``what``: "scene file", "study file"); a file that cannot
    be read, is not UTF-8, is not TOML or nests deeper than tomllib can read is an `error` naming
    the file (and the line where it knows it)."""
    try:
        raw = p.read_bytes()
    except OSError as e:
        raise error(f"{p}: cannot read the {what}: {e.strerror}") from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:  # TOML is UTF-8 by definition
        line = raw[: e.start].count(b"\n") + 1
        raise error(f"{p}:{line}: not UTF-8 text (byte 0x{raw[e.start]:02x} at offset {e.start}); "
                    "TOML files are UTF-8") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise error(f"{p}: not valid TOML: {e}") from None
    except RecursionError:  # tomllib parses nested arrays and inline tables recursively
        raise error(f"{p}: arrays or inline tables nested too deeply to read (deeper than Python's recursion "
                    f"limit of {sys.getrecursionlimit()}); no {what} needs more than a few levels") from None
    return data, _Source(p, text)
