"""recon: non-line-of-sight reconstruction from transient captures.

numpy/scipy only: this package never imports Mitsuba or drjit, so users with
measured data can use it without a renderer.
"""

__version__ = "0.1.0"
