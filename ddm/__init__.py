"""Driving-decision service (DDM): corridor world model, EV-response policy, path planner, command manager.

Pure cores: ``world`` (fusion), ``policy`` (EV response), ``paths`` (planner), ``commands`` (delivery
state machine), ``geometry`` (vectorised Frenet frame). ``service`` wires them to a Transport and a Clock.
"""
