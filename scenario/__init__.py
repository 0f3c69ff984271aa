"""Scripted experiments on the corridor: the demo, the lockstep runner, the fault runners and their judges.

Deployment (what an operator runs to deploy and operate a corridor: compose, ACL, keys, ``iea up``, status,
record/replay, the view) is ``deploy/``; this package runs scenarios on it and scores them on the
simulator's ground truth. ``iea demo`` and ``iea scenario run`` dispatch here from ``deploy/cli.py``.
"""
