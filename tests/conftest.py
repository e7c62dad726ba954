"""Where the tests find data: the project's own copies first, then ../shared/data
(developers' and CI's material beside the repository; DYNID_SHARED_DATA overrides)."""
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHARED_DATA = Path(os.environ.get("DYNID_SHARED_DATA", ROOT.parent / "shared" / "data"))
TX40_EXAMPLE = ROOT / "examples" / "staubli_tx40"

sys.path.insert(0, str(Path(__file__).resolve().parent))   # tests/oracles.py
