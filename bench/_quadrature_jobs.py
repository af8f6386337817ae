"""The quadrature benchmarks' captures, set up once: a :func:`transient_mi.render_capture.prepare_render` job (the
scene, its integrator and sensor, the manifest) and the :class:`~transient_mi.noise_target.NoiseTargetSpec` its
ratios are stated for. Nothing is written: ``tmp`` only names the output directory the job would use.

Used by ``bench_quadrature_cells_error.py``, ``bench_quadrature_parts.py`` and
``bench_quadrature_element_slope.py``.
"""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def letter_job(tmp, array: int, exposure_ms: float):
    """``scenes/nlos_letter.xml`` by the quadrature at ``array`` x ``array`` pixels (its 4 x 4 spots), ratios for
    the detector's defaults with the automatic gate at ``exposure_ms`` per spot: ``(job, spec)``."""
    from spad_detector import DetectorParams
    from transient_mi.noise_target import NoiseTargetSpec
    from transient_mi.render_capture import prepare_render

    spec = NoiseTargetSpec(target=0.1, params=DetectorParams(auto_gate=True), exposure_s=exposure_ms * 1e-3)
    job = prepare_render(ROOT / "scenes" / "nlos_letter.xml", Path(tmp) / "q",
                         defines={"estimator": "quadrature", "width": array, "height": array}, spp=1, seed=0,
                         noise_target=spec)
    return job, spec


def paper_demo_job(tmp, array: int, exposure_s: float):
    """The demo's capture of the paper scene (:class:`~transient_mi.paper.DemoSettings`, ``array`` x ``array``
    pixels), ratios for the paper's detector at ``exposure_s`` per spot: ``(job, spec)``."""
    from transient_mi.noise_target import NoiseTargetSpec
    from transient_mi.paper import DemoSettings, paper_detector, scene_file
    from transient_mi.render_capture import prepare_render

    ds = DemoSettings()
    cfg = ds.config(array)
    spec = NoiseTargetSpec(target=ds.noise_target, params=paper_detector(), exposure_s=exposure_s)
    job = prepare_render(scene_file(), Path(tmp) / "q", defines=cfg.defines(), spp=cfg.spp, seed=0,
                         noise_target=spec)
    return job, spec
