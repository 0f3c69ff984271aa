"""Eclipse SUMO as the simulator's traffic (``--traffic sumo``): SUMO drives every vehicle but the AVs.

``convert`` (pure): SUMO's frame, angles, signals and vehicle classes to the project's.
``network`` (pure XML + netconvert): a corridor's road as a SUMO network, and a road back from a network.
``demand`` (pure): a scenario's vehicles, flows and EV as a SUMO route file.
``corridor``: a corridor file from a SUMO network with RSUs placed along its edges.
``traffic`` (the libsumo shell): ``SumoTraffic``, a ``sim.traffic.TrafficModel``.

SUMO is an optional extra (``pip install '.[sumo]'``); ``require_sumo`` says how to install it.
"""

from __future__ import annotations

import importlib.util

TRAFFIC_MODELS = ("project", "sumo")
"""``project``: the simulator's own IDM/MOBIL traffic (``sim.traffic``); ``sumo``: Eclipse SUMO through libsumo."""

SUMO_INSTALL_HINT = ("SUMO traffic needs Eclipse SUMO and libsumo: pip install '.[sumo]' "
                     "(or: pip install 'eclipse-sumo>=1.28,<2' 'libsumo>=1.28,<2' 'sumolib>=1.28,<2')")


class SumoUnavailable(RuntimeError):
    """SUMO (libsumo, sumolib, the eclipse-sumo binaries) is not installed; the message says how to install it."""


def sumo_missing() -> str | None:
    """None when SUMO can run here; else why not and how to install it."""
    missing = [m for m in ("libsumo", "sumolib", "sumo") if importlib.util.find_spec(m) is None]
    if missing:
        return f"{', '.join(missing)} not installed. {SUMO_INSTALL_HINT}"
    return None


def require_sumo() -> None:
    """Raise ``SumoUnavailable`` (with the install command) when SUMO cannot run here."""
    why = sumo_missing()
    if why is not None:
        raise SumoUnavailable(why)


def check_traffic_model(name: str) -> str:
    """A traffic model name, validated (ValueError naming the choices)."""
    if name not in TRAFFIC_MODELS:
        raise ValueError(f"traffic model must be one of {TRAFFIC_MODELS}, got {name!r}")
    return name
