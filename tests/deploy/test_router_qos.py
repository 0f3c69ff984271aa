"""Every router the project configures forwards the blocking kinds without blocking (``ROUTER_NETWORK_QOS``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from deploy.acl import router_config
from protocol.corridor import load_corridor
from protocol.qos import BY_TOPIC, ROUTER_NETWORK_QOS

ROOT = Path(__file__).resolve().parents[2]


def _network_qos(conf) -> list[dict]:
    """The config's rules as zenoh parsed them, without the fields it fills with null."""
    def strip(d):
        return {k: strip(v) if isinstance(v, dict) else v for k, v in d.items() if v is not None}

    return [strip(rule) for rule in json.loads(conf.get_json("qos/network"))]


def _expected() -> list[dict]:
    return [{**rule, "overwrite": {k: v for k, v in rule["overwrite"].items() if v is not None}}
            for rule in ROUTER_NETWORK_QOS]


def test_the_rule_covers_exactly_the_blocking_kinds():
    (rule,) = ROUTER_NETWORK_QOS
    blocking = {t for t, q in BY_TOPIC.items() if q.congestion == "BLOCK"}
    assert blocking == {"cmd", "ack", "ev", "hazard"}
    assert rule["key_exprs"] == [f"**/{t}" for t in BY_TOPIC if t in blocking]
    assert rule["flows"] == ["egress"] and rule["overwrite"] == {"congestion_control": "drop"}


@pytest.mark.parametrize("path", ["deploy/zenoh/router.json5", "deploy/zenoh/mesh/router-core.json5",
                                  "deploy/zenoh/mesh/router-seg1.json5", "deploy/zenoh/mesh/router-seg2.json5"])
def test_shipped_router_configs_carry_it(path):
    import zenoh

    assert _network_qos(zenoh.Config.from_file(str(ROOT / path))) == _expected()


def test_generated_acl_config_and_iea_router_carry_it(tmp_path):
    import zenoh

    cfg = router_config(load_corridor(), "/run/secrets/dictionary.txt")
    assert cfg["qos"]["network"] == ROUTER_NETWORK_QOS
    f = tmp_path / "router.json5"
    f.write_text(json.dumps({"mode": "router"}))  # a user's config without it
    from protocol.router import router_config as iea_router_config

    assert _network_qos(iea_router_config([], str(f))) == _expected()
    assert zenoh  # parsed by zenoh itself above
