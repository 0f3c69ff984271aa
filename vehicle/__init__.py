"""IEA corridor vehicle process (thesis ch. 4): lateral + longitudinal control, bicycle plant, commands, fail-safe."""
