"""Standard V2X for the corridor: ETSI ITS Release 2 CAM, DENM and CPM in UPER (``codec``), built from and read
into the corridor's messages (``build``). The ASN.1 in ``asn1/release2/`` is ETSI's (BSD-3-Clause; notice in its
README.md and COPYRIGHT.md)."""

from protocol.v2x.codec import V2xError, V2xMessage, decode, encode

__all__ = ["V2xError", "V2xMessage", "decode", "encode"]
