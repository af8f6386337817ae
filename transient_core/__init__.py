"""transient_core: the Mitsuba-free foundation of transient-mi.

Everything the renderer, the detector model (:mod:`spad_detector`) and the
reconstruction toolbox (:mod:`recon`) share, and nothing that needs Mitsuba or
drjit, so a user with only measured data can read, write and check captures:

=====================  ===============================================================
:mod:`.stack`          the capture format: EXR histogram stack + ``manifest.json``
                       (the one reader and writer; see ``shared/DESIGN.md``)
:mod:`.units`          constants and unit conversions (c, ps <-> m, photons per pulse)
:mod:`.errors`         :class:`UserInputError`: one clear line for a user's mistake
:mod:`.atomic`         atomic files and directories (temporary name, then rename)
:mod:`.lock`           one writer per output directory
:mod:`.progress`       progress bars (rich), quiet when not on a terminal
=====================  ===============================================================

Dependency direction: ``transient_core`` <- ``spad_detector``, ``recon`` <-
``transient_mi`` (plug-ins, render pipeline, studies, CLI). Nothing here
imports anything of those.
"""

#: The version of the transient-mi distribution, stated here only: pyproject.toml reads it, and ``recon``,
#: ``transient_mi`` and the manifests' software versions take it from here.
__version__ = "0.1.0"
