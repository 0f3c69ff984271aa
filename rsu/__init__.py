"""Roadside unit: frame sources, detectors, SORT tracking, localisation, RSU service (DESIGN.md)."""
