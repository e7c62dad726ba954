"""Where the tests find data: the project's own copies first, then ../shared/data
(developers' and CI's material beside the repository; DYNID_SHARED_DATA overrides)."""
import os
import sys
from pathlib import Path

# Small QRs and matrix products are far slower with two BLAS threads on a loaded
# 2-core machine (measured 8x on W^T W chunks, 2.6x on a DIDIM step).
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("DYNID_SHARED_DATA", ROOT.parent / "shared" / "data"))
TX40_EXAMPLE = ROOT / "examples" / "staubli_tx40"

sys.path.insert(0, str(Path(__file__).resolve().parent))   # tests/oracles.py
