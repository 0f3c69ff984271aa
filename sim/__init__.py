"""Corridor simulator: world, traffic, EV, hazards, RSU camera model and renderer, scenarios,
dataset export. Replaces the thesis's Gazebo hybrid simulation (thesis 3.1)."""
