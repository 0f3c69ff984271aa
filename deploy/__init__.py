"""Deployment and operation: the umbrella CLI, corridor files, router configs, compose/ACL/key generation,
``iea up``, status, record/replay and the view. Scripted experiments and their judges are in ``scenario/``."""
