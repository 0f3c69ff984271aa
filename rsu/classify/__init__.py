"""EV identification (thesis 2.3-2.4, Framework B's second half): per-crop features and classifiers,
and per-track temporal evidence (flashing light bars) combined into an EV state."""
