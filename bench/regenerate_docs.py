#!/usr/bin/env python3
"""Rewrite every benchmark table and quoted number in README.md and docs/*.md from ``bench/results/*.json``.

A generated region is delimited by marker comments::

    <!-- bench:recon_table -->
    ...generated text...
    <!-- /bench -->

(on their own lines for blocks, or inline inside a sentence for a single
number). Everything between the markers is replaced by the output of the
generator of that name (:data:`GENERATORS`, the table of marker, generator,
records read and inline or block; the generators live in ``bench/docgen/``, one
module per part of the docs, beside ``docgen/common.py``'s shared provenance and
number formats), which reads only the committed JSON records (written by the
benchmark scripts with ``--save``; see ``bench/_record.py``). Every block ends with its provenance: the JSON file,
the command, the date and the machine the timings came from. A region whose
JSON file is missing says "not yet re-measured" instead of a number.

    python bench/regenerate_docs.py            # rewrite the files in place
    python bench/regenerate_docs.py --check    # exit 1 and name every region that differs (tests)
    python bench/regenerate_docs.py --list     # the generators and the records they read
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

ROOT = Path(__file__).resolve().parents[1]
MARKER = re.compile(r"<!-- bench:(?P<name>[a-z0-9_]+) -->(?P<body>.*?)<!-- /bench -->", re.S)

from docgen.common import Missing, Records, not_measured  # noqa: E402
from docgen.demo import (  # noqa: E402
    demo_exposures_table, demo_table, demo_wall_inline, demo_quick_inline, noise_demo_para, noise_cost_inline,
    noise_vs_spp_inline,
)
from docgen.rendering import (  # noqa: E402
    integrator_para, channels_para, volpath_para, volpath_mitransient_para, cornell_inline, gradient_para,
)
from docgen.nlos import nlos_readme_table, nlos_docs_table, nlos_pipeline_para, nlos_agreement, nlos_betas  # noqa: E402
from docgen.detector import detector_readme_inline, detector_para, detector_docs_table  # noqa: E402
from docgen.recon import (  # noqa: E402
    recon_readme_table, recon_docs_table, recon_speedups_inline, recon_targets_table, front_limit_inline,
    completion_limit_inline, completion_aspect_para, recon_quality_para, methods_trend_para,
)
from docgen.quadrature import (  # noqa: E402
    PAPER_ESTIMATORS, PROFILE_COMPARE, QUADRATURE_PARTS, QUADRATURE_PROFILES, QUADRATURE_SETTINGS, REFINEMENT_RULE,
    CELLS_CURVATURE, CELLS_ERROR, ELEMENT_SLOPE, LETTER_CURVATURE, cells_curvature_inline, letter_curvature_inline, SCENE_SETTINGS, cells_error_table, element_slope_inline, element_slope_table, paper_estimators_table, profile_compare_inline, quadrature_parts_table, quadrature_settings_table,
    QUADRATURE_PARTS_A4, cells_plan_para, PROFILE_OWNED, profile_owned_inline, CONFOCAL_BLOCKS, confocal_blocks_inline, MASSES, masses_inline,
    quadrature_cost_inline,
    quadrature_inline, quadrature_profile_inline, quadrature_table, refinement_rule_inline, scene_settings_table,
)
from docgen.nlos_quadrature import (array_speedup_inline, confocal_speedup_inline, nlos_quadrature_table,  # noqa: E402
                                    work_arrays_inline)
from docgen.fit_mesh import (GROWTH_PAIRS, fit_mesh_full_table, fit_mesh_growth_table,  # noqa: E402
                              fit_mesh_mannequin_para, fit_mesh_pixel_step_inline, fit_mesh_plane_table,
                              fit_mesh_table, fit_mesh_topology_table, fit_mesh_topology_16_table, TOPOLOGY_16,
                              TOPOLOGY_CLOSED, fit_mesh_topology_closed_table,
                              visibility_memo_para)
from docgen.studies import (  # noqa: E402
    studies_para, _study_inline, dataset_para, dataset_docs_table, dataset_nlos_inline, view_para, view_docs_table,
    fit_para, dataset_noise_standard_table, DATASET_NT, fit_quadrature_cost_table,
)


# ----------------------------------------------------------------------------- marker -> (generator, records, inline)

GENERATORS = {
    "demo_wall": (demo_wall_inline, ["demo"], True),
    "demo_quick": (demo_quick_inline, ["demo_quick"], True),
    "demo_table": (demo_table, ["demo"], False),
    "demo_exposures": (demo_exposures_table, ["demo"], False),
    "detector_inline": (detector_readme_inline, ["detector"], True),
    "cornell_render": (cornell_inline, ["integrator"], True),
    "integrator": (integrator_para, ["integrator"], False),
    "volpath": (volpath_para, ["volpath"], False),
    "volpath_mitransient": (volpath_mitransient_para, ["volpath_mitransient"], False),
    "channels": (channels_para, ["channels"], False),
    "nlos_table": (nlos_readme_table, ["nlos"], False),
    "nlos_docs_table": (nlos_docs_table, ["nlos"], False),
    "nlos_pipeline": (nlos_pipeline_para, ["nlos"], False),
    "nlos_agreement": (nlos_agreement, ["nlos"], False),
    "nlos_betas": (nlos_betas, ["nlos"], True),
    "detector": (detector_para, ["detector"], False),
    "detector_docs_table": (detector_docs_table, ["detector"], False),
    "recon_table": (recon_readme_table, ["recon"], False),
    "recon_docs_table": (recon_docs_table, ["recon"], False),
    "recon_speedups": (recon_speedups_inline, ["recon"], True),
    "studies": (studies_para, ["studies"], False),
    "study_photon_quick": (_study_inline("photon_quick"), ["studies"], True),
    "study_array_quick": (_study_inline("array_quick"), ["studies"], True),
    "study_photon_default": (_study_inline("photon_default"), ["studies"], True),
    "study_array_default": (_study_inline("array_default"), ["studies"], True),
    "dataset": (dataset_para, ["dataset_dataset_example"], False),
    "noise_demo": (noise_demo_para, ["noise_target"], False),
    "view": (view_para, ["view"], False),
    "view_docs_table": (view_docs_table, ["view"], False),
    "noise_cost": (noise_cost_inline, ["render_variance_cost", "render_variance_cost_16k"], True),
    "noise_vs_spp": (noise_vs_spp_inline, ["render_noise_vs_spp"], True),
    "dataset_docs_table": (dataset_docs_table, ["dataset_dataset_example"], False),
    "dataset_nlos": (dataset_nlos_inline, ["dataset_dataset_nlos_mannequin"], True),
    "dataset_noise_standard": (dataset_noise_standard_table, list(DATASET_NT), False),
    "gradient": (gradient_para, ["gradient"], False),
    "fit": (fit_para, ["fit", "fit_adam", "fit_16", "fit_8"], False),
    "fit_quadrature_cost": (fit_quadrature_cost_table, ["fit_quadrature_cost_32"], False),
    "front_limit": (front_limit_inline, ["front_surface_limit"], True),
    "completion_limit": (completion_limit_inline, ["front_surface_limit"], True),
    "recon_quality": (recon_quality_para, ["mannequin_features", "study_methods_nlos_letter",
                                           "front_surface_limit"], False),
    "methods_trend": (methods_trend_para, ["study_methods_paper_mannequin"], False),
    "completion_aspect": (completion_aspect_para, ["completion_aspect"], False),
    "quadrature_table": (quadrature_table, ["quadrature"], False),
    "quadrature_inline": (quadrature_inline, ["quadrature"], True),
    "quadrature_cost": (quadrature_cost_inline, ["quadrature_cost"], True),
    "quadrature_profile": (quadrature_profile_inline, list(QUADRATURE_PROFILES), True),
    "refinement_rule": (refinement_rule_inline, [REFINEMENT_RULE], True),
    "quadrature_profile_compare": (profile_compare_inline, list(PROFILE_COMPARE), True),
    "quadrature_profile_owned": (profile_owned_inline, list(PROFILE_OWNED), True),
    "confocal_blocks": (confocal_blocks_inline, list(CONFOCAL_BLOCKS), True),
    "quadrature_masses": (masses_inline, list(MASSES), True),
    "paper_estimators": (paper_estimators_table, list(PAPER_ESTIMATORS), False),
    "quadrature_settings": (quadrature_settings_table, [QUADRATURE_SETTINGS], False),
    "quadrature_parts": (quadrature_parts_table, [QUADRATURE_PARTS], False),
    "cells_plan": (cells_plan_para, [QUADRATURE_PARTS_A4], False),
    "quadrature_scene_settings": (scene_settings_table, list(SCENE_SETTINGS), False),
    "quadrature_cells_error": (cells_error_table, [CELLS_ERROR], False),
    "quadrature_cells_curvature": (cells_curvature_inline, [CELLS_ERROR, CELLS_CURVATURE], True),
    "quadrature_letter_curvature": (letter_curvature_inline, list(LETTER_CURVATURE), True),
    "element_slope": (element_slope_table, [ELEMENT_SLOPE], False),
    "element_slope_inline": (element_slope_inline, [ELEMENT_SLOPE], True),
    "nlos_quadrature_table": (nlos_quadrature_table, ["nlos_quadrature", "nlos_quadrature_64x64",
                                                      "nlos_quadrature_confocal"], False),
    "nlos_quadrature_array": (array_speedup_inline, ["nlos_quadrature_array"], True),
    "nlos_quadrature_confocal": (confocal_speedup_inline, ["nlos_quadrature_confocal"], True),
    "work_arrays": (work_arrays_inline, ["work_arrays"], True),
    "fit_mesh": (fit_mesh_table, ["fit_mesh_letter"], False),
    "fit_mesh_plane": (fit_mesh_plane_table, ["fit_mesh_tilted_plane"], False),
    "fit_mesh_topology": (fit_mesh_topology_table, ["fit_mesh_chair", "fit_mesh_holed_plate"], False),
    "fit_mesh_topology_16": (fit_mesh_topology_16_table, list(TOPOLOGY_16), False),
    "fit_mesh_topology_closed": (fit_mesh_topology_closed_table, list(TOPOLOGY_CLOSED), False),
    "fit_mesh_full": (fit_mesh_full_table, ["fit_mesh_letter_16", "fit_mesh_tilted_plane_16"], False),
    "fit_mesh_mannequin": (fit_mesh_mannequin_para, ["fit_mesh_mannequin", "fit_mesh_mannequin_step2",
                                                     "fit_mesh_mannequin_step4"], False),
    "fit_mesh_pixel_step": (fit_mesh_pixel_step_inline, ["fit_mesh_mannequin", "fit_mesh_mannequin_step2",
                                                         "fit_mesh_mannequin_step4"], True),
    "visibility_memo": (visibility_memo_para, ["visibility_memo_letter_8"], False),
    "fit_mesh_growth": (fit_mesh_growth_table, [n for name, _ in GROWTH_PAIRS for n in (f"{name}_grow0", name)],
                        False),
    "recon_targets": (recon_targets_table, ["study_methods_paper_mannequin", "study_methods_nlos_letter",
                                            "mannequin_features", "recon_methods", "completion_seeds"], False),
}

# ----------------------------------------------------------------------------- driver


def render(name: str, R) -> str:
    if name not in GENERATORS:
        raise SystemExit(f"error: unknown bench marker '{name}'; known: {', '.join(sorted(GENERATORS))}")
    fn, needs, inline = GENERATORS[name]
    try:
        text = fn(R)
    except Missing as e:
        text = not_measured([str(e)], inline)
    # a block stands on its own lines with a blank line before its closing marker (ends tables and paragraphs)
    return text if inline else "\n" + text.strip("\n") + "\n\n"


def documents(root: Path) -> list[Path]:
    return [root / "README.md", *sorted((root / "docs").glob("*.md"))]


def regenerate(root: Path, results: Path, check: bool) -> list[str]:
    """Rewrite (or, with ``check``, compare) every marked region; returns the regions that differed."""
    sys.path.insert(0, str(ROOT))
    from transient_core.atomic import atomic_file

    R = Records(results)
    differ = []
    for doc in documents(root):
        if not doc.is_file():
            continue
        text = doc.read_text()

        def sub(m):
            new = render(m.group("name"), R)
            if new != m.group("body"):
                differ.append(f"{doc.relative_to(root)}: bench:{m.group('name')}")
            return f"<!-- bench:{m.group('name')} -->{new}<!-- /bench -->"

        out = MARKER.sub(sub, text)
        if out != text and not check:
            with atomic_file(doc) as tmp:
                tmp.write_text(out)
    return differ


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--check", action="store_true", help="change nothing; exit 1 if any region differs")
    ap.add_argument("--list", action="store_true", help="list the generators and the records they read")
    ap.add_argument("--root", type=Path, default=ROOT, help="repository root holding README.md and docs/")
    ap.add_argument("--results", type=Path, default=None, help="results folder (default ROOT/bench/results)")
    a = ap.parse_args(argv)
    if a.list:
        for k, (_, needs, inline) in GENERATORS.items():
            print(f"{k:24s} {'inline' if inline else 'block '}  {', '.join(f'bench/results/{n}.json' for n in needs)}")
        return 0
    results = a.results or a.root / "bench" / "results"
    differ = regenerate(a.root, results, a.check)
    if a.check:
        for d in differ:
            print(f"differs from its JSON: {d}")
        if differ:
            print("run: python bench/regenerate_docs.py", file=sys.stderr)
        return 1 if differ else 0
    for d in differ:
        print(f"rewrote {d}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
