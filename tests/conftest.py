"""Shared pytest configuration.

Mitsuba/drjit state is per process; tests that render import ``transient_mi``
(which selects ``llvm_ad_mono``). Tests of ``recon`` and of the detector
model must not need Mitsuba.
"""

import os

os.environ.setdefault("TRANSIENT_MI_PROGRESS", "0")


def pytest_terminal_summary(terminalreporter):
    """The reliability suites' counts (docs/reliability.md), visible in CI's log whatever the capture mode."""
    import sys

    fault = sys.modules.get("test_fault_injection")
    if fault is not None:
        kinds = sorted({what.split()[0] + (" " + what.split()[1] if what.startswith("render") else "")
                        for what, _ in fault.KILL_POINTS})
        terminalreporter.write_line(f"reliability: fault injection: {len(fault.KILL_POINTS)} kill -9 points over "
                                    f"{len(kinds)} commands and render modes ({', '.join(kinds)})")
    conc = sys.modules.get("test_concurrency")
    if conc is not None:
        terminalreporter.write_line(f"reliability: concurrency: {len(conc.COMMANDS)} writing commands refuse a "
                                    "second writer; stale locks taken over")
    walk = sys.modules.get("test_bad_input_walk")
    rep = getattr(walk, "REPORT", None)
    if rep:
        terminalreporter.write_line(f"reliability: bad-input walk: {rep['walked']} bad values over {rep['commands']} "
                                    f"commands, {rep['handled']} handled: {rep['refused']} refused in one line (exit "
                                    f"2, nothing written), {len(rep['accepted_huge'])} huge values accepted")
