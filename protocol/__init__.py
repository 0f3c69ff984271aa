"""The contract every IEA service shares: messages, codec, key expressions, transports, clock, corridor."""

from protocol.codec import ProtocolError, decode, encode
from protocol.messages import SCHEMA_VERSION

__all__ = ["ProtocolError", "SCHEMA_VERSION", "decode", "encode"]
