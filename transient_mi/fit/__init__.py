"""Inverse NLOS: fit a parametric model of the hidden scene to a counts capture (analysis by synthesis).

Public API: :func:`fit_capture` (what ``transient-mi fit`` runs), :class:`FitSettings`,
:class:`~transient_mi.fit.twin.MannequinTwin` (the mannequin's differentiable twin) and the models of
:mod:`transient_mi.fit.models`. See ``docs/fit.md``.
"""

from .api import FitSettings, fit_capture
from .models import MannequinModel, PatchesModel
from .twin import MannequinTwin

__all__ = ["fit_capture", "FitSettings", "MannequinTwin", "MannequinModel", "PatchesModel"]
