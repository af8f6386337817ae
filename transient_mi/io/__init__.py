"""Capture I/O for transient-mi.

The EXR stack format is implemented once, in :mod:`recon.io.stack` (numpy and
OpenEXR only, so that ``recon`` can read captures without Mitsuba); this
module re-exports it.
"""

from recon.io.stack import *  # noqa: F401,F403
from recon.io.stack import __all__  # noqa: F401
