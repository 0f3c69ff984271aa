"""Fuzz targets of ``bench/fuzz_bench.py`` for the V2X decoders (``protocol/v2x/codec.py``): CAM, DENM and CPM.

Seeds are UPER messages made by the project's builders (an EV's CAM, an active and a cleared DENM, CPMs of 0, 3
and 10 objects). Inputs: the seeds themselves, byte-level mutants (``Mutator.byte_payload``: bit flips,
truncation, insertion, splicing, random bytes, an oversized payload, trailing bytes) and value-level mutants (one
integer, bit string or choice of the decoded value replaced, re-encoded without constraint checks so that the
bytes carry out-of-range values, then a header byte changed now and then). The only accepted failure is
``V2xError``.
"""

from __future__ import annotations

import random
from typing import Any

from bench.fuzz_targets import Target
from protocol.examples import example_messages, object_list
from protocol.messages import EvAlert
from protocol.v2x.build import ev_cam, ev_denm, rsu_cpm
from protocol.v2x.codec import V2xError, decode, encode
from protocol.v2x.schema import specification

_TYPE = {"CAM": "CAM", "DENM": "DENM", "CPM": "CollectivePerceptionMessage"}


def v2x_seeds(kind: str) -> list[bytes]:
    """Valid UPER messages of ``kind`` built by the project."""
    if kind == "CAM":
        return [encode("CAM", ev_cam(7, 1.7e9, 30.63, -96.47, h, s, lb, sir))
                for h, s, lb, sir in ((0.0, 0.0, False, False), (1.2, 25.0, True, True), (-2.0, 13.0, True, False))]
    if kind == "DENM":
        alert = next(m for _k, m in example_messages("fuzz", stamp=10.0) if isinstance(m, EvAlert))
        cleared = alert.model_copy(update={"state": "cleared"})
        return [encode("DENM", ev_denm(a, 9, 12.0)) for a in (alert, cleared)]
    return [encode("CPM", rsu_cpm(object_list(n, 10.0), 9, 30.63, -96.47, 0.0, 0.0)) for n in (0, 3, 10)]


class V2xDecodeTarget(Target):
    def __init__(self, rng: random.Random, kind: str) -> None:
        self.kind = kind
        self.name = f"decode_v2x_{kind}"
        super().__init__(rng)

    def seeds(self) -> list[bytes]:
        return v2x_seeds(self.kind)

    def _mutate_value(self, node: Any) -> Any:
        r = self.rng
        if isinstance(node, dict) and node:
            k = r.choice(list(node))
            return {**node, k: self._mutate_value(node[k])}
        if isinstance(node, list) and node:
            i = r.randrange(len(node))
            return [*node[:i], self._mutate_value(node[i]), *node[i + 1:]]
        if isinstance(node, tuple) and len(node) == 2 and isinstance(node[0], str):
            return (node[0], self._mutate_value(node[1]))
        if isinstance(node, bool):
            return not node
        if isinstance(node, int):
            return r.choice((node + 1, node - 1, -node, 0, 2**31, 65535, node * 1000))
        if isinstance(node, bytes):
            return bytes(r.getrandbits(8) for _ in range(r.choice((0, 1, len(node), 300))))
        if isinstance(node, tuple) and len(node) == 2 and isinstance(node[0], bytes):
            return (bytes(r.getrandbits(8) for _ in node[0]), node[1])
        return node

    def payload(self) -> bytes:
        r = self.rng.random()
        if r < 0.12:
            return self.rng.choice(self.mutator.seeds)
        if r < 0.35:
            seed = self.rng.choice(self.mutator.seeds)
            try:  # out-of-range values in otherwise well-formed bytes (no constraint check on this encode)
                value = specification().decode(_TYPE[self.kind], seed)
                data = bytearray(specification().encode(_TYPE[self.kind], self._mutate_value(value)))
            except Exception:  # noqa: BLE001 - the mutant does not encode: a byte mutant instead
                return self.mutator.byte_payload()
            if data and self.rng.random() < 0.2:
                data[self.rng.randrange(min(2, len(data)))] = self.rng.choice((0, 1, 2, 3, 14, 255))
            return bytes(data)
        return self.mutator.byte_payload()

    def feed(self, payload: bytes) -> bool:
        try:
            decode(payload, self.kind if self.rng.random() < 0.9 else None)
        except V2xError:
            return False
        return True


def v2x_targets() -> dict[str, Any]:
    return {f"decode_v2x_{k}": (lambda rng, k=k: V2xDecodeTarget(rng, k)) for k in ("CAM", "DENM", "CPM")}

