"""Driving-decision service (DDM): world model, EV and hazard policies, path planner, command manager.

Decisions flow one way: inputs update the world model (``world``: tracks fused by ``fusion`` into
``tracks``, EV alerts, hazards fused by ``hazard_fusion``, vehicles); each step the decider (``decider``)
takes its immutable picture (``picture``), the pure policies (``policy.ev``, ``policy.hazard``, sharing the
rules of ``manoeuvre`` and the planner ``paths``) turn it into intents (``intent``), and the command
manager (``commands``) turns those into commands. ``geometry`` is the vectorised road (Frenet) frame.
``service`` wires them to a Transport and a Clock; ``build`` assembles one DDM, ``cli`` parses its options.
"""
