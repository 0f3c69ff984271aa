"""The mutation engine of ``bench/fuzz_bench.py``: fuzz payloads from valid seeds.

- structure-aware mutations of the msgpack tree: a field replaced by NaN/inf/huge/negative/zero
  numbers, wrong types, over-long strings, deep nesting, a list grown past its cap or to thousands of
  items, a field deleted or an unknown one added, the kind or version changed; numeric perturbations
  (1e300 metres, 2**53 ids) that the codec must refuse or the handler must survive;
- byte-level mutations: bit flips, truncation, insertion, splicing, random bytes, an oversized payload.
"""

from __future__ import annotations

import math
import random
from typing import Any

import msgpack

from protocol.codec import MAX_PAYLOAD_BYTES
from protocol.messages import MAX_ACTORS, MAX_OBJECTS, MAX_WAYPOINTS, MESSAGE_TYPES

# ----------------------------------------------------------------------------- mutation engine
_NUMBERS: tuple[Any, ...] = (
    0, -0.0, 1, -1, 0.5, -0.5, 5e-324, 1e-308, 1e308, -1e308, 1.7976931348623157e308, math.nan, math.inf, -math.inf,
    2**31, -(2**31), 2**53, 2**53 + 1, 2**63 - 1, -(2**63), 2**64 - 1, 1e16, -1e16, 4 * math.pi + 1e-9, 90.0000001,
    -180.0000001, 15, 16, 255, 256, 65535, 1e6, -1e6, 1e9, 3.0, 100.0)
_OTHERS: tuple[Any, ...] = (
    None, True, False, "", "x" * 65, "y" * 300, "\x00", "../../etc", "é", "av1", "rsu1", "ddm", "*", "a/b",
    b"", b"\x00" * 63, b"\x00" * 64, b"\xff" * 65, [], {}, [1, 2], [1.0, 2.0, 3.0], {"a": 1}, {"kind": "Health"},
    [[0.0, 0.0]], [[1e308, -1e308]] * 3)
_KINDS = tuple(m.KIND for m in MESSAGE_TYPES) + ("", "kind", "Nope")


def _deep(depth: int) -> Any:
    v: Any = 0
    for _ in range(depth):
        v = [v]
    return v


class Mutator:
    """Produces fuzz payloads from seed messages (see the module docstring for the operators)."""

    def __init__(self, rng: random.Random, seeds: list[bytes]) -> None:
        self.rng = rng
        self.seeds = seeds
        self.oversize = b"\x91" + b"\xc0" * (MAX_PAYLOAD_BYTES + 1)

    # -- tree level
    def _paths(self, tree: Any) -> list[tuple]:
        out: list[tuple] = []

        def walk(node: Any, path: tuple, depth: int) -> None:
            out.append(path)
            if depth > 4:
                return
            if isinstance(node, dict):
                for k, v in node.items():
                    walk(v, (*path, k), depth + 1)
            elif isinstance(node, list):
                idx = range(len(node)) if len(node) <= 4 else self.rng.sample(range(len(node)), 4)
                for i in idx:
                    walk(node[i], (*path, i), depth + 1)

        walk(tree, (), 0)
        return out

    @staticmethod
    def _get(tree: Any, path: tuple) -> Any:
        for p in path:
            tree = tree[p]
        return tree

    def _set(self, tree: Any, path: tuple, value: Any) -> Any:
        if not path:
            return value
        try:  # an earlier mutation of this round may have replaced the parent
            self._get(tree, path[:-1])[path[-1]] = value
        except (KeyError, IndexError, TypeError):
            pass
        return tree

    def _value_like(self, old: Any) -> Any:
        r = self.rng
        if isinstance(old, bool):
            return r.choice((not old, 0, 1, None))
        if isinstance(old, int):
            return r.choice((old + r.randint(-3, 3), old * r.choice((-1, 2, 1000)), r.getrandbits(r.choice((8, 32, 53))),
                             r.choice(_NUMBERS)))
        if isinstance(old, float):
            return r.choice((old * r.choice((-1.0, 0.0, 1e3, 1e-3, 1e6, 1e300)), old + r.gauss(0.0, 50.0),
                             r.uniform(-1e4, 1e4), r.choice(_NUMBERS)))
        if isinstance(old, str):
            return r.choice((old + "x", old[:-1], old * r.randint(2, 40), "".join(r.choice("abc-_.é/* \x00")
                                                                                  for _ in range(r.randint(0, 80)))))
        if isinstance(old, bytes):
            return bytes(r.getrandbits(8) for _ in range(r.choice((0, 63, 64, 65, 200))))
        return r.choice(_OTHERS + _NUMBERS)

    def mutate_tree(self, tree: Any) -> Any:
        r = self.rng
        paths = self._paths(tree)
        for _ in range(r.choice((1, 1, 1, 2, 3, 4))):
            path = r.choice(paths)
            try:
                old = self._get(tree, path)
            except (KeyError, IndexError, TypeError):
                continue
            op = r.random()
            if op < 0.35:
                tree = self._set(tree, path, self._value_like(old))
            elif op < 0.55:
                tree = self._set(tree, path, r.choice(_NUMBERS + _OTHERS))
            elif op < 0.65 and isinstance(old, list) and old:
                cap = r.choice((len(old) * 2, MAX_OBJECTS + 1, MAX_WAYPOINTS + 1, MAX_ACTORS + 1, 5000))
                tree = self._set(tree, path, [r.choice(old)] * cap)  # shared items: packed as copies
            elif op < 0.72 and path:
                try:
                    parent = self._get(tree, path[:-1])
                except (KeyError, IndexError, TypeError):
                    continue
                if isinstance(parent, dict):
                    parent.pop(path[-1], None)
                elif isinstance(parent, list) and parent:
                    parent.pop(path[-1] if path[-1] < len(parent) else -1)
            elif op < 0.78 and isinstance(old, dict):
                old[r.choice(("extra", "auth", "kind", "v", "x" * 70, "seq"))] = r.choice(_NUMBERS + _OTHERS)
            elif op < 0.84 and isinstance(tree, dict):
                tree[r.choice(("kind", "v"))] = r.choice(_KINDS + (0, 2, -1, None, 1))
            elif op < 0.88:
                tree = self._set(tree, path, _deep(r.choice((20, 200, 2000))))
            elif op < 0.94 and isinstance(old, list) and old:
                tree = self._set(tree, path, old[: r.randint(0, len(old))])
            else:
                tree = self._set(tree, path, self._value_like(old))
        return tree

    def tree_payload(self, mutate: bool = True) -> bytes:
        seed = self.rng.choice(self.seeds)
        if not mutate:
            return seed
        tree = msgpack.unpackb(seed, raw=False)  # a fresh tree (faster than deepcopy)
        if mutate:
            tree = self.mutate_tree(tree)
        try:
            return msgpack.packb(tree, use_bin_type=True)
        except (OverflowError, ValueError, TypeError):
            return self.rng.choice(self.seeds)

    # -- byte level
    def byte_payload(self) -> bytes:
        r = self.rng
        data = bytearray(r.choice(self.seeds))
        op = r.random()
        if op < 0.3:
            for _ in range(r.randint(1, 8)):
                if data:
                    i = r.randrange(len(data))
                    data[i] ^= 1 << r.randrange(8)
        elif op < 0.45:
            del data[r.randrange(len(data) + 1):]
        elif op < 0.6:
            i = r.randrange(len(data) + 1)
            data[i:i] = bytes(r.getrandbits(8) for _ in range(r.randint(1, 16)))
        elif op < 0.7:
            other = r.choice(self.seeds)
            data = data[: r.randrange(len(data) + 1)] + other[r.randrange(len(other) + 1):]
        elif op < 0.8:
            data = bytearray(r.getrandbits(8) for _ in range(r.choice((0, 1, 2, 5, 17, 100, 1000))))
        elif op < 0.83:
            return self.oversize
        elif op < 0.9:
            data += bytes(r.getrandbits(8) for _ in range(r.randint(1, 8)))  # trailing bytes
        else:
            i = r.randrange(len(data) + 1)
            data[i:i] = bytes([r.choice((0xDC, 0xDD, 0xDE, 0xDF, 0xC9, 0xC6, 0xDB))]) + b"\xff\xff\xff\xff"
        return bytes(data)

    def __call__(self) -> bytes:
        p = self.rng.random()
        if p < 0.12:
            return self.tree_payload(mutate=False)  # valid: keeps the handler's state realistic
        if p < 0.72:
            return self.tree_payload()
        return self.byte_payload()
