"""The paper's settings live in one place (transient_mi/paper.py) that the scene, the demo and the experiment read."""

from __future__ import annotations

import re

from transient_mi.paper import (BEGIN, END, PAPER, PAPER_BOUNDS_M, PaperConfig, paper_detector, scene_defaults,
                                scene_file, xml_defaults_block)


def test_scene_defaults_are_written_from_paper_py():
    """The ``<default>`` block of scenes/paper_mannequin.xml is the one paper.py writes
    (``python -m transient_mi.paper --write-xml``), and the scene defines nothing else by default."""
    text = scene_file().read_text()
    block = re.search(re.escape(BEGIN) + r".*?" + re.escape(END), text, re.S).group(0)
    assert block.strip() == xml_defaults_block().strip()
    defaults = re.findall(r'<default name="([^"]+)" value="([^"]*)"/>', text)
    assert defaults == scene_defaults()


def test_scene_uses_every_paper_value_through_a_parameter():
    """No paper value is typed into the scene body: each fixed fact appears only as ``$name``."""
    text = scene_file().read_text()
    body = text[text.index(END):]
    for name, _ in scene_defaults():
        assert f"${name}" in body, f"default {name} is not used by the scene"
    for literal in ("1550", "50e6", "0.0254", "-2.0"):
        assert literal not in body, f"{literal} typed into the scene body"


def test_demo_and_experiment_read_paper_py():
    import transient_mi.demo as demo
    import transient_mi.experiment as experiment

    assert experiment.PaperConfig is PaperConfig and experiment.paper_detector is paper_detector
    assert demo.PAPER is PAPER and demo.PAPER_BOUNDS_M is PAPER_BOUNDS_M
    d = paper_detector()
    assert (d.pde, d.jitter_ps, d.dark_count_rate_cps, d.gate_transition_ps, d.tcspc_max_count_rate_hz) == (
        PAPER.pde, PAPER.jitter_ps, PAPER.dark_count_rate_cps, PAPER.gate_transition_ps,
        PAPER.tcspc_max_count_rate_hz)
    assert PaperConfig().bin_width_ps == PAPER.tcspc_bin_width_ps


def test_rendered_scene_carries_the_paper_values():
    import transient_mi  # noqa: F401
    import mitsuba as mi

    scene = mi.load_file(str(scene_file()), array="4", spots="1")
    laser = [e for e in scene.emitters() if type(e).__name__ == "PulsedLaser"][0]
    assert abs(laser.wavelength_nm - PAPER.wavelength_nm) < 1e-9
