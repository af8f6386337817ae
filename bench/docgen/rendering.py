"""Renderer regions: transient vs steady path tracing, media, channels, gradients (docs/benchmarks.md,
docs/rendering.md, docs/media.md, docs/polarization.md, docs/differentiable.md).
"""

from __future__ import annotations

from docgen.common import Missing, provenance


def integrator_para(R) -> str:
    rec = R("integrator")
    r = rec["result"]
    st = r.get("settings", {})
    t, p = r["transient_path"], r["path"]
    rounds = ", ".join(f"{100 * x:.0f} %" for x in r.get("throughput_ratio_per_round", []))
    return (f"\n**Transient vs steady path tracing** (`python bench/bench_integrator.py`: Cornell box, "
            f"{st.get('size', 256)} x {st.get('size', 256)}, {t['spp']} spp, max depth {st.get('max_depth', 8)}): "
            f"`transient_path` with a {st.get('bins', 1024)}-bin film keeps {100 * r['throughput_ratio']:.0f} % of "
            f"Mitsuba's `path` throughput ({t['paths_per_s'] / 1e6:.2f} vs {p['paths_per_s'] / 1e6:.2f} M paths/s, "
            f"best of each; per round {rounds}; goal >= {100 * r['goal_ratio']:.0f} %); peak RSS "
            f"{t['peak_rss_mb']:.0f} MB ({p['peak_rss_mb']:.0f} MB for `path`), of which the film is "
            f"{r['film_bytes'] / 1e6:.0f} MB. {provenance(rec)}\n")


def channels_para(R) -> str:
    rec = R("channels")
    r = rec["result"]
    st = r["settings"]
    o = r["overhead_over_mono"]
    return (f"\n**Cost of channels per bin** (`python bench/bench_channels.py`: `scenes/cornell_box.xml`, "
            f"{st['size']} x {st['size']}, {st['bins']} bins, {st['spp']} spp, max depth {st['max_depth']}, best of "
            f"{st['rounds']} rounds, second of two renders timed), render time against `llvm_ad_mono` (one value "
            f"per bin): `llvm_ad_rgb` recording R, G, B per bin {100 * o['rgb']:+.0f} %; the same variant recording "
            f"one value per bin (`channels=\"mono\"`) {100 * o['rgb_transport_mono_bins']:+.0f} %, so the cost is "
            f"the per-bin channels (one histogram each), not the colour transport; `llvm_ad_mono_polarized` "
            f"recording S0..S3 per bin {100 * o['stokes']:+.0f} %"
            + (f"; `llvm_ad_spectral` recording R, G, B per bin {100 * o['spectral_rgb']:+.0f} % and six 50 nm "
               f"wavelength bands per bin (`spectral_bands_nm`) {100 * o['spectral_bands']:+.0f} %"
               if "spectral_bands" in o else "")
            + f". {provenance(rec)}\n")


def volpath_para(R) -> str:
    rec = R("volpath")
    r = rec["result"]
    st = r["settings"]
    t, p = r["transient_volpath"], r["volpath"]
    rounds = ", ".join(f"{100 * x:.0f} %" for x in r["throughput_ratio_per_round"])
    return (f"\n**Transient vs steady volumetric path tracing** (`python bench/bench_volpath.py`: "
            f"`scenes/fog_camera.xml`, {st['size']} x {st['size']}, {st['spp']} spp, max depth {st['max_depth']}): "
            f"`transient_volpath` with a {st['bins']}-bin film renders {100 * r['throughput_ratio']:.0f} % of "
            f"Mitsuba's `volpath` throughput ({t['paths_per_s'] / 1e6:.2f} vs {p['paths_per_s'] / 1e6:.2f} M paths/s, "
            f"best round of each, second of two renders timed; per round {rounds}; goal >= "
            f"{100 * r['goal_ratio']:.0f} %). {provenance(rec)}\n")


def volpath_mitransient_para(R) -> str:
    rec = R("volpath_mitransient")
    r = rec["result"]
    e, x = r["efficiency"], r["cross_check"]
    o, m = e["transient-mi"], e["mitransient"]
    eps = sorted(r["speedup_at_equal_error"], key=float)[-1]
    sp = r["speedup_at_equal_error"][eps]
    hi = str(r["spp_hi"])
    return (f"\n**Against mitransient's `transient_prbvolpath`** (`python bench/bench_volpath_mitransient.py`: a "
            f"camera outside a `null` cube of homogeneous medium on a floor under an area light, {r['size']} x "
            f"{r['size']}, {r['n_bins']} bins of {r['bin_width_ps']:g} ps, unlimited depth; each renderer in its own "
            f"process, {r['rounds']} alternating rounds, best times): transient-mi {o['time_s'][hi]:.2f} s and "
            f"mitransient {m['time_s'][hi]:.2f} s for {r['spp_hi']} spp, the same error per sample (relative RMS "
            f"error of one {r['spp_hi']}-spp render {o['relative_rmse_at_spp_hi']:.3f} vs "
            f"{m['relative_rmse_at_spp_hi']:.3f}), so transient-mi reaches a relative error of {100 * float(eps):g} % "
            f"in {1 / sp:.2f}x mitransient's time ({'faster' if sp > 1 else 'slower'}); peak memory "
            f"{o['peak_rss_mb']:.0f} vs {m['peak_rss_mb']:.0f} MB. Cross-check: the means agree within Monte Carlo "
            f"error ({x['comparisons']} Welch comparisons of {r['replicates']} + {r['replicates']} replicates, the "
            f"image total and the pixel-summed profile in groups of bins, family-wise false-failure rate "
            f"{x['family_false_failure_rate']:g}: largest |t| {x['max_abs_t']:.2f}, {x['max_abs_t_over_bound']:.2f} of "
            f"its bound; image totals differ by {100 * x['image_total_relative_difference']:+.3f} %). "
            f"{provenance(rec)}\n")


def cornell_inline(R) -> str:
    rec = R("integrator")
    x = rec["result"].get("readme_example")
    if not x or x.get("status") != "ok":
        raise Missing("integrator")
    return (f"{x['render_time_s']:.1f} s of rendering ({x['wall_s']:.0f} s for the whole command) on "
            f"{rec['machine']['cores']} CPU cores ({provenance(rec, short=True)})")


def gradient_para(R) -> str:
    rec = R("gradient")
    r = rec["result"]
    st = r["settings"]
    runs = r["runs"]

    def one(key, what):
        x = runs[key]
        p, g = x["primal"], x["gradient"]
        return (f"{what} {g['best_s']:.3f} s vs {p['best_s']:.3f} s (time ratio {x['time_ratio']:.2f}), peak RSS "
                f"{g['peak_rss_mb']:.0f} vs {p['peak_rss_mb']:.0f} MB ({x['peak_rss_ratio']:.2f})")

    return (f"\n**Cost** (`python bench/bench_gradient.py`: one reverse-mode gradient of a {st['size']} x "
            f"{st['size']} confocal, {st['bins']}-bin capture of `scenes/nlos_letter.xml` against the primal at the "
            f"same spp, {st['spp']}, best of {st['rounds']} warm calls, primal and gradient in separate processes): "
            f"{one('bsdf', 'gradient of four reflectances and the pulse energy')}; "
            f"{one('geometry', 'with the translation of the letter as well (geometry, arrival-time term)')}; "
            f"{one('bsdf_depth8', 'reflectances and pulse energy at `max_depth` 8 (path replay)')}. Targets: <= "
            f"{r['targets']['time_ratio_max']:g} in both. {provenance(rec)}\n")
