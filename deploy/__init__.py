"""Deployment: the umbrella CLI, corridor files, router configs and compose generation."""
