"""Writing preview, reconstruction, demo and study pictures leaves the session's matplotlib backend alone.

(``matplotlib.use("Agg")`` inside the library switched a Jupyter session to Agg, after which
``plt.show()`` drew nothing: the notebooks' figures disappeared after the first render.)
"""

import os
import subprocess
import sys
import textwrap
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _run(code: str) -> str:
    """Run ``code`` in a fresh interpreter whose session backend is ``svg``; its last printed line."""
    env = dict(os.environ, MPLBACKEND="svg", TRANSIENT_MI_PROGRESS="0")
    r = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], capture_output=True, text=True, env=env,
                       cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stderr
    return r.stdout.strip().splitlines()[-1]


def test_library_pictures_keep_the_session_backend(tmp_path):
    out = _run(f"""
        import os
        import matplotlib.pyplot as plt, numpy as np
        before = plt.get_backend()
        from transient_mi.preview import write_preview
        m = {{"capture": "camera", "time": {{"t0_ps": 0.0, "bin_width_ps": 10.0, "n_bins": 8}}}}
        write_preview({str(tmp_path / "p.png")!r}, np.random.default_rng(0).random((4, 5, 8)), m)
        from recon.synthetic import point_capture
        import recon
        cap = point_capture([(0.0, 0.0, 0.5)], mode="confocal", pixels=8)
        rec = recon.reconstruct(cap, "bp", voxels=8, bounds=(-0.5, 0.5, -0.5, 0.5, 0.3, 0.7))
        recon.write_outputs({str(tmp_path / "rec")!r}, rec)
        from transient_mi.reporting import save_figure, subplots
        fig, ax = subplots(1, 2, figsize=(4, 2))
        ax[0].plot([0, 1])
        save_figure(fig, {str(tmp_path / "r.png")!r})
        assert os.path.getsize({str(tmp_path / "r.png")!r}) > 0
        assert os.path.getsize({str(tmp_path / "p.png")!r}) > 0
        assert os.path.getsize({str(tmp_path / "rec" / "projection_z.png")!r}) > 0
        print(before, plt.get_backend())
    """)
    before, after = out.split()
    assert before == "svg" and after == "svg"
