# The first code cell of every notebook: `# %% [setup]` in a source expands to this text, with
# __NOTEBOOK__ replaced by the notebook's name (notebooks/build.py). One copy here, so that every
# notebook still opens and runs on its own.
import os
import shutil
import sys
from pathlib import Path

SMALL = os.environ.get("TRANSIENT_MI_NOTEBOOK_SMALL") == "1"  # tiny settings (the test suite)


def find_repo_root(start: Path) -> Path | None:
    """The transient-mi checkout this notebook lives in (None when the package is pip-installed)."""
    for d in (start, *start.parents):
        if (d / "transient_mi" / "__init__.py").is_file() and (d / "recon").is_dir():
            return d
    return None


ROOT = find_repo_root(Path.cwd())
if ROOT is not None:
    sys.path.insert(0, str(ROOT))  # use this checkout's transient_mi and recon
OUT = Path(os.environ.get("TRANSIENT_MI_NOTEBOOK_OUT") or (ROOT or Path.cwd()) / "out" / "notebooks") / "__NOTEBOOK__"
shutil.rmtree(OUT, ignore_errors=True)
OUT.mkdir(parents=True)

import matplotlib.pyplot as plt
import numpy as np

plt.rcParams.update({"figure.dpi": 72, "savefig.dpi": 72, "font.size": 9})
