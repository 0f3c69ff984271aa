"""Typed, validated reading of TOML tables (corridor and scenario files share it)."""

from __future__ import annotations

import math
from typing import Any


class FieldReader:
    """Typed access to one table of a parsed TOML file; every failure names the file, the field and
    what was expected, raised as ``error`` (a ``ValueError`` subclass of the caller's choosing)."""

    def __init__(self, source: str, data: dict[str, Any], path: str = "", error: type[ValueError] = ValueError) -> None:
        self.source, self.data, self.path, self.error = source, data, path, error

    def _where(self, key: str) -> str:
        return f"{self.path}.{key}" if self.path else key

    def fail(self, key: str, expected: str, got: Any = None) -> ValueError:
        got_s = "" if got is None else f", got {got!r}"
        return self.error(f"{self.source}: field '{self._where(key)}': expected {expected}{got_s}")

    def has(self, key: str) -> bool:
        return key in self.data

    def num(self, key: str, default: float | None = None, lo: float | None = None,
            hi: float | None = None, *, positive: bool = False) -> float:
        if key not in self.data:
            if default is None:
                raise self.fail(key, "a number (missing)")
            return float(default)
        v = self.data[key]
        if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v):
            raise self.fail(key, "a finite number", v)
        if positive and not v > 0:
            raise self.fail(key, "a number > 0", v)
        if lo is not None and v < lo or hi is not None and v > hi:
            raise self.fail(key, f"a number in [{lo}, {hi}]", v)
        return float(v)

    def integer(self, key: str, default: int | None = None, *, lo: int = 0, hi: int = 10**9) -> int:
        if key not in self.data:
            if default is None:
                raise self.fail(key, "an integer (missing)")
            return default
        v = self.data[key]
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise self.fail(key, f"an integer in [{lo}, {hi}]", v)
        return v

    def text(self, key: str, default: str | None = None, choices: tuple[str, ...] | None = None, *,
             ident: bool = False) -> str:
        if key not in self.data:
            if default is None:
                raise self.fail(key, "a string (missing)")
            return default
        v = self.data[key]
        if not isinstance(v, str) or not v:
            raise self.fail(key, "a non-empty string", v)
        if choices is not None and v not in choices:
            raise self.fail(key, f"one of {list(choices)}", v)
        if ident and not all(c.isalnum() or c in "_-." for c in v):
            raise self.fail(key, "an id of letters, digits, '_', '-', '.'", v)
        return v

    def table(self, key: str, required: bool = True) -> FieldReader:
        if key not in self.data:
            if required:
                raise self.fail(key, "a table (missing)")
            return FieldReader(self.source, {}, self._where(key), self.error)
        v = self.data[key]
        if not isinstance(v, dict):
            raise self.fail(key, "a table", type(v).__name__)
        return FieldReader(self.source, v, self._where(key), self.error)

    def tables(self, key: str, required: bool = True) -> list[FieldReader]:
        if key not in self.data:
            if required:
                raise self.fail(key, "an array of tables (missing)")
            return []
        v = self.data[key]
        if not isinstance(v, list) or not all(isinstance(x, dict) for x in v):
            raise self.fail(key, "an array of tables ([[...]])", type(v).__name__)
        return [FieldReader(self.source, x, f"{self._where(key)}[{i}]", self.error) for i, x in enumerate(v)]

    def str_list(self, key: str) -> list[str]:
        v = self.data.get(key, [])
        if not isinstance(v, list) or not all(isinstance(x, str) for x in v):
            raise self.fail(key, "a list of strings", v)
        return list(v)

    def optional_table(self, key: str) -> FieldReader | None:
        return self.table(key) if key in self.data else None

    def check_keys(self, allowed: set[str]) -> None:
        unknown = sorted(set(self.data) - allowed)
        if unknown:
            raise self.error(f"{self.source}: unknown field(s) {unknown} in '{self.path or 'top level'}'; "
                             f"allowed: {sorted(allowed)}")
