"""An RSU's uplink budget: bulk thinned to the configured rate, alerts and health never held back."""

import pytest

from protocol.clock import SimClock
from protocol.keys import rsu_key
from protocol.local_bus import LocalBus
from rsu.uplink import (
    PER_MESSAGE_OVERHEAD_B,
    ShapedTransport,
    UplinkBudget,
    is_bulk_key,
    validate_uplink_bit_s,
)


def test_bulk_rate_settles_at_the_share_of_the_uplink():
    budget = UplinkBudget(16_000, share=0.5)  # 1,000 B/s for bulk
    sent_b = 0
    for k in range(15 * 60):  # 1,400 B object lists offered at 15 Hz for a minute
        if budget.allow(1400, k / 15):
            sent_b += 1400 + PER_MESSAGE_OVERHEAD_B
    assert sent_b == pytest.approx(1000 * 60, rel=0.05)  # the bucket's fill (plus its first second's depth)
    assert budget.skipped > 0.9 * 15 * 60


def test_alerts_always_go_and_bulk_waits_after_them():
    budget = UplinkBudget(16_000, burst_s=1.0)  # 1,000 B/s, one second deep, starts full
    assert budget.allow(800, 0.0)
    assert budget.allow(800, 0.0)  # not in debt: goes, and takes the bucket 760 B into debt
    assert not budget.allow(10, 0.0)
    budget.spend(140, 0.0)  # an alert goes regardless: 980 B of debt
    assert budget.tokens_b == pytest.approx(-980.0)
    assert not budget.allow(100, 0.9)
    assert budget.allow(100, 1.0)  # the debt repaid at 1,000 B/s


def test_keys_classed_by_their_kind():
    assert is_bulk_key(rsu_key("c", "rsu1", "objects"))
    assert is_bulk_key("iea/c/rsu/rsu1/camera/jpeg")
    assert not is_bulk_key(rsu_key("c", "rsu1", "ev"))
    assert not is_bulk_key(rsu_key("c", "rsu1", "health"))


def test_shaped_transport_drops_bulk_not_alerts():
    bus, clock = LocalBus(), SimClock(0.0)
    got: list[str] = []
    bus.subscribe_bytes("iea/c/**", lambda k, _p: got.append(k.rsplit("/", 1)[-1]))
    shaped = ShapedTransport(bus, UplinkBudget(8_000, burst_s=1.0), clock)  # 500 B/s, 500 B deep
    for _ in range(5):
        shaped.publish_bytes(rsu_key("c", "rsu1", "objects"), b"x" * 300)
        shaped.publish_bytes(rsu_key("c", "rsu1", "ev"), b"a" * 200)
    assert got.count("ev") == 5
    assert got.count("objects") == 1
    assert shaped.budget.skipped == 4
    shaped.publish_bytes("iea/c/rsu/rsu1/camera/jpeg", b"j" * 30_000)  # deeper than the bucket: never
    clock.advance(60.0)
    shaped.publish_bytes("iea/c/rsu/rsu1/camera/jpeg", b"j" * 30_000)
    assert "jpeg" not in got


@pytest.mark.parametrize("bad", [0.0, 500.0, float("nan"), float("inf"), -16_000.0])
def test_a_rate_that_is_no_rate_is_refused(bad):
    with pytest.raises(ValueError, match="at least 1000 bit/s"):
        validate_uplink_bit_s(bad)
    assert validate_uplink_bit_s(None) is None


def test_bulk_nobody_subscribes_to_is_not_counted_against_the_uplink():
    class Unwatched(LocalBus):
        def wait_for_subscribers(self, key, timeout_s):
            return not key.endswith("/jpeg")  # nobody watches the camera

    bus, clock = Unwatched(), SimClock(0.0)
    shaped = ShapedTransport(bus, UplinkBudget(16_000), clock)  # 1,000 B/s, 2 s deep
    for _ in range(10):
        shaped.publish_bytes("iea/c/rsu/rsu1/camera/jpeg", b"j" * 1500)  # Zenoh sends these nowhere
    assert shaped.budget.tokens_b == shaped.budget.depth_b and shaped.budget.skipped == 0
    shaped.publish_bytes(rsu_key("c", "rsu1", "objects"), b"o" * 1500)
    assert shaped.budget.tokens_b < shaped.budget.depth_b
