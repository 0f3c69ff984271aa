"""The RSU camera renderer: a posed, shaded view of a world snapshot (``renderer``), its per-frame geometry
(``pose``), its per-frame lamp and light numbers (``effects``) and the ground-truth labels of a frame (``labels``)."""
