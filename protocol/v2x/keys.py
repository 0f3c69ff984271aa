"""Key expressions of the corridor's standard V2X traffic (payloads are bytes, not the corridor's msgpack):

    iea/{c}/v2x/rsu/{rsu}/cpm     UPER CPM of the RSU's objects (TS 103 324): for any ITS station
    iea/{c}/v2x/rsu/{rsu}/denm    UPER DENM of the RSU's active EV alert (TS 103 831, cause 95)
    iea/{c}/v2x/obu/{station}/cam a vehicle's CAM as its radio sends it (a signed V2X envelope, protocol/v2x/secure.py)
    iea/{c}/v2x/rsu/{rsu}/rx      what the RSU's radio received, passed on to the DDM in an envelope signed by the RSU
"""

from __future__ import annotations

from protocol.keys import ROOT, KeyError_, _chunk

RSU_V2X_TOPICS = ("cpm", "denm", "rx")


def v2x_rsu_key(corridor: str, rsu_id: str, topic: str) -> str:
    if topic not in RSU_V2X_TOPICS:
        raise KeyError_(f"unknown RSU V2X topic {topic!r}; expected one of {RSU_V2X_TOPICS}")
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/v2x/rsu/{_chunk(rsu_id, 'rsu id')}/{topic}"


def v2x_obu_cam_key(corridor: str, station: str) -> str:
    """The key a vehicle's radio broadcasts its CAM on (``station``: the vehicle id)."""
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/v2x/obu/{_chunk(station, 'station')}/cam"


def v2x_obu_cam_expr(corridor: str) -> str:
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/v2x/obu/*/cam"


def v2x_rsu_expr(corridor: str, topic: str) -> str:
    if topic not in RSU_V2X_TOPICS:
        raise KeyError_(f"unknown RSU V2X topic {topic!r}; expected one of {RSU_V2X_TOPICS}")
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/v2x/rsu/*/{topic}"


def v2x_expr(corridor: str) -> str:
    """Every V2X key of the corridor."""
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/v2x/**"
