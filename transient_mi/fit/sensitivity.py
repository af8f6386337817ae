"""Which pixels and time bins respond to one parameter of a model: forward-mode derivatives of a capture.

:func:`parameter_sensitivity` renders d(capture)/d(parameter) of a fit model (e.g. the mannequin's
``elbow_right``) in a counts capture's scene, with the renderer's forward mode
(:func:`transient_mi.integrators._nlos_ad.nlos_forward`): the tangent enters at the parameter, flows through
the model's Dr.Jit vertices into the render. Used by notebook 06 and ``docs/make_fit_figures.py``.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

__all__ = ["parameter_sensitivity"]


def parameter_sensitivity(model, capture, theta, name: str, *, spot: int = 0, seed: int = 1, spp: int = 64,
                          sigma_ps: float = 30.0) -> np.ndarray:
    """d(ideal capture)/d(``name``) of ``model`` at ``theta`` for one laser spot.

    Parameters
    ----------
    model : MannequinModel or PatchesModel
        The fit model (its ``names`` hold ``name``).
    capture : CaptureModel
        The capture whose scene is rendered (built for ``model``'s mesh).
    theta : array
        Parameter vector, the model's units.
    name : str
        The parameter to differentiate (e.g. ``"elbow_right"``, degrees).
    spot, seed, spp, sigma_ps
        Laser spot, random seed, samples per pixel, the film's temporal kernel (ps).

    Returns
    -------
    numpy.ndarray
        ``[height, width, n_bins]`` photons per pulse per unit of the parameter (per degree, per metre).
    """
    from transient_mi.integrators._nlos_ad import nlos_forward

    if name not in model.names:
        raise ValueError(f"{name!r} is not a parameter of the {model.name} model; allowed: {', '.join(model.names)}")
    k = model.names.index(name)
    t = [mi.Float(float(x)) for x in theta]
    dr.enable_grad(t[k])
    v = model._vertices(t)
    flat = dr.ravel(v if isinstance(v, mi.Point3f) else mi.Point3f(*(dr.concat(list(c)) for c in v)))
    dr.set_grad(t[k], 1.0)
    tangent = dr.forward_to(flat)  # d(vertices)/d(parameter), evaluated before the render's symbolic scopes
    leaf = mi.Float(dr.detach(flat))
    dr.enable_grad(leaf)
    dr.set_grad(leaf, dr.detach(tangent))
    capture.params[capture.vkey] = leaf
    capture.params[capture.rkey] = type(capture.params[capture.rkey])(model.albedo(theta))
    capture.params.update()
    capture.sensor.film().kernel_sigma_ps = float(sigma_ps)
    capture.sensor.forget_nlos_setup()
    try:
        d = nlos_forward(capture.integrator, capture.scene, capture.params, capture.sensor, int(seed), int(spp),
                         spots=[int(spot)])
        return np.asarray(d, dtype=np.float64).reshape(capture.height, capture.width, capture.n_bins)
    finally:
        dr.disable_grad(capture.params[capture.vkey])
        capture.params[capture.vkey] = dr.detach(capture.params[capture.vkey])
        capture.params.update()


def sensitivity_figure(d: np.ndarray, t0_ps: float, bin_width_ps: float, name: str, unit: str = "deg",
                       t_range_ns=(15.0, 22.0)):
    """Two panels: per pixel, the sum over bins of ``|d|``; and the x-t slice of the row that responds most
    (signed: red where light arrives after the change, blue where it left). ``d``: ``[height, width, bins]``."""
    from transient_mi.reporting import subplots

    fig, ax = subplots(1, 2, figsize=(9, 3.3))
    im = ax[0].imshow(np.abs(d).sum(-1), origin="lower", cmap="magma")
    ax[0].set_title(f"sum over bins of |d capture / d {name}|", fontsize=9)
    ax[0].set_xlabel("pixel x")
    ax[0].set_ylabel("pixel y")
    fig.colorbar(im, ax=ax[0], label=f"photons per pulse per {unit}")
    row = int(np.argmax(np.abs(d).sum(axis=(1, 2))))
    lim = float(np.abs(d[row]).max()) or 1.0
    n = d.shape[-1]
    ax[1].imshow(d[row], aspect="auto", origin="lower", cmap="RdBu_r", vmin=-lim, vmax=lim,
                 extent=(t0_ps / 1000, (t0_ps + n * bin_width_ps) / 1000, -0.5, d.shape[1] - 0.5))
    ax[1].set_xlim(*t_range_ns)
    ax[1].set_xlabel("arrival time (ns)")
    ax[1].set_ylabel("pixel x")
    ax[1].set_title(f"d capture / d {name}, pixel row {row} (red: later, blue: earlier)", fontsize=9)
    fig.tight_layout()
    return fig
