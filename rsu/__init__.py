"""Roadside unit: frame sources, detectors, SORT tracking, localisation, RSU service (docs/architecture.md §Perception pipeline)."""
