"""Shared pytest configuration.

Mitsuba/drjit state is per process; tests that render import ``transient_mi``
(which selects ``llvm_ad_mono``). Tests of ``recon`` and of the detector
model must not need Mitsuba.
"""

import os

os.environ.setdefault("TRANSIENT_MI_PROGRESS", "0")
