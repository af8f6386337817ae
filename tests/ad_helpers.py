"""What the differentiable-rendering tests share: the loss ``<w, hist>``, its reverse-mode gradient, central
differences along a colour direction, the Welch comparison of AD with finite differences, and detaching every
parameter. Import ``transient_mi`` before this module (it imports mitsuba)."""

from __future__ import annotations

import math

import numpy as np

import drjit as dr
import mitsuba as mi

from stats_helpers import ALPHA, t_bound, welch_df


def weighted_sum(img, w) -> float:
    """``sum(w * img)`` in float64 (the scalar loss every comparison differentiates)."""
    return float(np.sum(np.asarray(img, dtype=np.float64) * np.asarray(w)))


def reverse_gradient(scene, key, w, seed, spp):
    """Reverse-mode derivative of ``sum(w * render)`` with respect to the first value of ``params[key]``."""
    params = mi.traverse(scene)
    dr.enable_grad(params[key])
    params.update()
    img = mi.render(scene, params, seed=seed, spp=spp)
    dr.backward(dr.sum(img * w, axis=None))
    g = float(np.asarray(dr.grad(params[key])).ravel()[0])
    dr.disable_grad(params[key])
    params.update()
    return g


def loss_at(scene, key, value, w, seed, spp):
    """``sum(w * render)`` with ``params[key]`` set to ``value`` (restored afterwards)."""
    params = mi.traverse(scene)
    base = float(np.asarray(params[key]).ravel()[0])
    params[key] = value
    params.update()
    out = weighted_sum(mi.render(scene, seed=seed, spp=spp), w)
    params[key] = base
    params.update()
    return out


def color_direction_gradient(scene, params, key, x0, direction, w, seed, mode, spp):
    """Derivative of ``sum(w * render)`` along ``params[key] = x0 + direction * t`` at ``t = 0`` (a ``Color3f``
    parameter), in reverse (``mode="reverse"``) or forward mode; ``params[key]`` is restored to ``x0``."""
    th = mi.Float(0.0)
    dr.enable_grad(th)
    params[key] = x0 + mi.Color3f(*direction) * th
    params.update()
    img = mi.render(scene, params, seed=seed, spp=spp)
    if mode == "reverse":
        dr.backward(dr.sum(img * w, axis=None))
        g = float(dr.grad(th)[0])
    else:
        dr.forward(th)
        g = weighted_sum(dr.grad(img), w)
    params[key] = mi.Color3f(dr.detach(x0))
    params.update()
    return g


def color_direction_loss(scene, params, key, x0, direction, c, w, seed, spp):
    """``sum(w * render)`` at ``params[key] = x0 + direction * c`` (restored to ``x0`` afterwards)."""
    params[key] = mi.Color3f(dr.detach(x0)) + mi.Color3f(*direction) * c
    params.update()
    out = weighted_sum(mi.render(scene, seed=seed, spp=spp), w)
    params[key] = mi.Color3f(dr.detach(x0))
    params.update()
    return out


def assert_welch(ad, fd, n_tests, what):
    """Welch t of the AD mean against the FD mean, at family-wise false-failure rate ``ALPHA`` over ``n_tests``
    comparisons; the AD mean must also be resolved (more than 10 standard errors from 0)."""
    ad, fd = np.asarray(ad), np.asarray(fd)
    va, vb = ad.var(ddof=1), fd.var(ddof=1)
    se = math.sqrt(va / len(ad) + vb / len(fd))
    bound = t_bound(min(len(ad), len(fd)), ALPHA, n_tests, df=welch_df(va, len(ad), vb, len(fd)))
    assert abs(ad.mean()) > 10 * se, f"{what}: the gradient is not resolved ({ad.mean():.4g} +- {se:.3g})"
    assert abs(ad.mean() - fd.mean()) < bound * se, \
        f"{what}: AD {ad.mean():.4g} vs FD {fd.mean():.4g} +- {se:.3g} (bound {bound:.2f} se)"


def detach_all(params):
    """Leave no parameter attached to the AD graph: a live shape whose to_world stays attached makes every later
    symbolic loop that calls shapes (any scene: Dr.Jit's calls reach every registered instance) differentiable
    in reverse mode, which the camera AD loops refuse."""
    for key in params.keys():
        try:
            v = params[key]
            on = dr.grad_enabled(v)
        except Exception:  # noqa: BLE001 (not a Dr.Jit value)
            continue
        if on:
            params[key] = type(v)(dr.detach(v))
    params.update()
