"""Without SUMO, ``--traffic sumo`` says how to install it and exits 2 (the rest of the project needs no SUMO)."""

from __future__ import annotations

import pytest

import sim.sumo

HINT = "not installed. " + sim.sumo.SUMO_INSTALL_HINT


@pytest.fixture
def no_sumo(monkeypatch):
    monkeypatch.setattr(sim.sumo, "sumo_missing", lambda: f"libsumo {HINT}")


def test_iea_sim_run_without_sumo_exits_2_with_the_install_command(no_sumo, capsys):
    from sim.cli import main

    assert main(["run", "rellis_ev_yield", "--traffic", "sumo"]) == 2
    assert "pip install '.[sumo]'" in capsys.readouterr().err


def test_iea_scenario_run_without_sumo_exits_2(no_sumo, capsys):
    from deploy.scenario_cli import main as scenario_main

    assert scenario_main(["run", "rellis_ev_yield", "--inprocess", "--fast", "--traffic", "sumo"]) == 2
    assert "pip install '.[sumo]'" in capsys.readouterr().err


def test_iea_up_without_sumo_exits_2(no_sumo, capsys):
    from deploy.up import main

    assert main(["--traffic", "sumo", "--no-sim"]) == 2
    assert "pip install '.[sumo]'" in capsys.readouterr().err


def test_require_sumo_names_the_install_command(no_sumo):
    with pytest.raises(sim.sumo.SumoUnavailable, match=r"pip install"):
        if (why := sim.sumo.sumo_missing()) is not None:
            raise sim.sumo.SumoUnavailable(why)


def test_the_sim_passes_traffic_to_its_process():
    from deploy.procs import corridor_services
    from protocol.corridor import load_corridor

    specs = corridor_services(load_corridor(), "c1", scenario="rellis_ev_yield", duration_s=5.0, run_dir="/tmp/x",
                              traffic="sumo")
    sim_args = next(s for s in specs if s.name == "sim").args
    assert sim_args[sim_args.index("--traffic") + 1] == "sumo"
    plain = corridor_services(load_corridor(), "c1", scenario="rellis_ev_yield", duration_s=5.0, run_dir="/tmp/x")
    assert "--traffic" not in next(s for s in plain if s.name == "sim").args  # the demo: the project's traffic
