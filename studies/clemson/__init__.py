"""The Clemson hazard-navigation comparison: an on-board end-to-end steering CNN driving from a dashboard camera
(the report's cases 1-3) against the infrastructure-guided thesis controller, on the same seeded debris roads.

- ``dashcam``: the car's dashboard cameras, rendered by the corridor's renderer;
- ``driving``: the hazard episodes, the teacher and the lockstep runs;
- ``export``: the driving data set the steering nets train on;
- ``learned_steering``: the learned steering as an on-board component of the vehicle process.

``python -m studies.clemson --help`` runs the export and the vehicle with learned steering.
"""
