"""``transient-mi view``: a local web viewer for captures, detection and reconstruction (Bokeh).

Optional: ``pip install 'transient-mi[view]'`` (Bokeh; imageio-ffmpeg for MP4 videos).
Nothing here is imported by the core package; the command imports it when run.

Modules: :mod:`.data` (what is under the viewed path, and reading it),
:mod:`.capture_panel`, :mod:`.detector_panel`, :mod:`.recon_panel` (the three tabs),
:mod:`.app` (the page), :mod:`.server` (Bokeh server and the read-only file route),
:mod:`.video` (time slices as GIF/MP4; Pillow only, no Bokeh). See ``docs/view.md``.
"""

from __future__ import annotations

__all__ = ["require_bokeh"]


def require_bokeh() -> None:
    """Raise :class:`transient_core.errors.UserInputError` with the install line when Bokeh is missing."""
    try:
        import bokeh  # noqa: F401
    except ImportError:
        from transient_core.errors import UserInputError

        raise UserInputError("the viewer needs Bokeh: pip install 'transient-mi[view]'") from None
