"""``IEA_LOG_LEVEL`` sets the RSU's, the DDM's and the vehicle's default log level (one ``--log-level`` for all);
a bad value fails with a message."""

from __future__ import annotations

import pytest

from ddm import cli as ddm_cli
from rsu import cli as rsu_cli
from vehicle import cli as vehicle_cli


def test_env_sets_the_default_log_level(monkeypatch):
    monkeypatch.setenv("IEA_LOG_LEVEL", "debug")
    assert rsu_cli.build_parser().parse_args(["--rsu", "rsu1", "--source", "sim"]).log_level == "DEBUG"
    assert ddm_cli.build_parser().parse_args(["run"]).log_level == "DEBUG"
    assert vehicle_cli.build_parser().parse_args(["run"]).log_level == "DEBUG"
    monkeypatch.delenv("IEA_LOG_LEVEL")
    assert rsu_cli.build_parser().parse_args(["--rsu", "rsu1", "--source", "sim"]).log_level == "INFO"


@pytest.mark.parametrize("main", [rsu_cli.main, ddm_cli.main, vehicle_cli.main])
def test_bad_env_log_level_is_refused_with_a_message(monkeypatch, capsys, main):
    monkeypatch.setenv("IEA_LOG_LEVEL", "loud")
    with pytest.raises(SystemExit) as e:
        main(["--rsu", "rsu1", "--source", "sim"] if main is rsu_cli.main else ["run"])
    assert e.value.code == 2 and "IEA_LOG_LEVEL='LOUD'" in capsys.readouterr().err
