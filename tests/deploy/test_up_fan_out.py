"""`iea up` decodes each corridor message once and hands it to every reader (monitor, health, extras)."""

from deploy.up import fan_out


def test_every_reader_gets_the_message_even_when_one_raises(caplog):
    got = []

    def broken(key, msg):
        raise RuntimeError("reader bug")

    readers = [lambda k, m: got.append(("a", k, m)), broken, lambda k, m: got.append(("b", k, m))]
    fan_out(readers, "iea/c/sim/world", 7)
    assert got == [("a", "iea/c/sim/world", 7), ("b", "iea/c/sim/world", 7)]
    assert "reader bug" in caplog.text
