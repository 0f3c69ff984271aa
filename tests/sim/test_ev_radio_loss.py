"""--ev-radio-loss: `iea up` and `iea-sim run` set the loss of an equipped EV's radio; a value that is not a
probability stops them with exit 2 and says why."""

from __future__ import annotations

import pytest

from protocol.corridor import load_corridor
from protocol.local_bus import LocalBus


def test_iea_sim_run_refuses_a_loss_that_is_not_a_probability(capsys):
    from sim.cli import main

    with pytest.raises(SystemExit) as exc:
        main(["run", "ev_equipped_unseen", "--ev-radio-loss", "1.5"])
    assert exc.value.code == 2
    assert "--ev-radio-loss: must be a probability in [0, 1], got 1.5" in capsys.readouterr().err


def test_iea_up_passes_the_loss_to_the_simulator_and_refuses_a_bad_one(tmp_path, capsys):
    from deploy.up import Up
    from deploy.up import build_parser as up_parser
    from sim.cli import build_parser as sim_parser

    up = Up(scenario="ev_equipped_unseen", run_dir=tmp_path / "run", port=0, v2x=True, ev_radio_loss=0.3)
    sim = next(s for s in up.specs if s.name == "sim")
    parsed = sim_parser().parse_args(sim.args[2:])  # after "-m sim"
    assert parsed.ev_radio_loss == 0.3 and parsed.ev_key == str(up.ev_key)
    plain = Up(scenario="ev_equipped_unseen", run_dir=tmp_path / "run2", port=0)
    assert "--ev-radio-loss" not in next(s for s in plain.specs if s.name == "sim").args
    assert up_parser().parse_args(["--ev-radio-loss", "0.3"]).ev_radio_loss == 0.3
    with pytest.raises(SystemExit) as exc:
        up_parser().parse_args(["--ev-radio-loss", "-0.1"])
    assert exc.value.code == 2 and "must be a probability in [0, 1]" in capsys.readouterr().err
    with pytest.raises(ValueError, match="ev_radio_loss must be a probability"):
        Up(scenario="ev_equipped_unseen", run_dir=tmp_path / "run3", port=0, ev_radio_loss=1.5)


def test_start_radio_puts_the_loss_in_its_radio_model():
    from sim.ev_radio import start_radio

    corridor = load_corridor(None)
    radio = start_radio(LocalBus(), corridor, "c1", loss=0.3)
    try:
        assert radio.transport.channel.loss == 0.3
    finally:
        radio.close()
        radio.transport.close()
    radio = start_radio(LocalBus(), corridor, "c1")
    try:
        assert radio.transport.channel.loss == corridor.transport.dsrc_loss
    finally:
        radio.close()
        radio.transport.close()
