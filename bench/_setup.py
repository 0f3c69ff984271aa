"""Imported first by the bench scripts: one thread per numeric library (their figures are one-core costs; the
variables must be set before numpy loads), and the repository on ``sys.path`` when a script runs from a checkout
whose project is not installed (``make test`` installs it editable, which puts it there already)."""

import os
import sys
from pathlib import Path

for _var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

ROOT = Path(__file__).resolve().parent.parent
"""The repository."""
REAL = ROOT.parent / "shared" / "data" / "real"
"""The real data (videos, photos, the COCO YOLOX-Nano) of ``../shared`` beside the repository."""
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))
