"""One writer per output, for every command that writes (transient_core.lock, docs/reliability.md).

For each command, the output's lock is held by another live process (a real process: ``sleep``, whose lock
record names it as the first writer): the second writer is refused in one line naming that run, writes nothing
and leaves the first one's lock alone, so the first finishes undisturbed. Then the first process dies without
releasing its lock: the next run takes the stale lock over, finishes, and leaves no lock behind. Runs are in
this process (no Mitsuba import each); nothing sleeps or races: the owner is alive or dead when the run starts.
(tests/test_output_lock.py checks the lock itself: reused pids, unreadable locks, other hosts, and a second
process refused while this one holds the lock.)
"""

from __future__ import annotations

import json
import subprocess

import numpy as np
import pytest

from detector_helpers import make_ideal_capture
from fault_helpers import ROOT, run_cli
from transient_core import lock as _lock

NLOS_D = ["-D", "width=2", "-D", "height=2", "-D", "spots_x=1", "-D", "spots_y=1", "-D", "n_bins=8",
          "-D", "bin_width_ps=256"]


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    d = tmp_path_factory.mktemp("conc_inputs")
    data = np.zeros((1, 2, 2, 24), np.float32)
    data[..., 10:13] = 1e-3
    make_ideal_capture(d / "ideal", data, bin_width_ps=64.0)
    (d / "spec.yaml").write_text("scene: cornell_box\nseed: 1\nspp: 1\n"
                                 "defines: {width: 2, height: 2, n_bins: 8, bin_width_ps: 600}\n")
    return d


#: command -> (argv with {out}, whether the run after a stale lock is made here: the long ones are only refused;
#: fit's is left out to keep CI fast, 15-25 s of derivative kernels compiled for one iteration)
COMMANDS = {
    "render": (["render", ROOT / "scenes" / "nlos_point_targets.xml", "-o", "{out}", *NLOS_D, "--spp", "1"], True),
    "detect": (["detect", "{ideal}", "-o", "{out}", "--pulses", "100"], True),
    "recon": (["recon", "{ideal}", "-o", "{out}", "--voxels", "4", "--no-plots",
                "--threshold", "none"], True),
    "export": (["export", "{ideal}", "{out}.h5", "--to", "ytal"], True),
    "video": (["video", "{ideal}", "-o", "{out}.gif"], True),
    "mannequin": (["mannequin", "-o", "{out}.ply", "--detail", "8"], True),
    "scene-mesh": (["scene-mesh", ROOT / "scenes" / "nlos_point_targets.xml", "-o", "{out}.ply"], True),
    "fit": (["fit", "{ideal}", "-o", "{out}", "--model", "patches", "--bin-width-ps", "128", "--iterations", "1",
             "--spp", "4", "--spp-residual", "4", "--no-progress"], False),
    "demo": (["demo", "--quick", "-o", "{out}"], False),
    "study photon-budget": (["study", "photon-budget", "-o", "{out}", "--quick"], False),
    "study array-size": (["study", "array-size", "-o", "{out}", "--quick", "--arrays", "2"], False),
    "study methods": (["study", "methods", "-o", "{out}", "--quick", "--arrays", "2"], False),
    "dataset": (["dataset", "{spec}", "-o", "{out}", "--workers", "1"], False),
}


def _argv(template, inputs, out):
    subst = {"{out}": str(out), "{ideal}": str(inputs / "ideal"), "{spec}": str(inputs / "spec.yaml")}
    argv = []
    for a in map(str, template):
        for k, v in subst.items():
            a = a.replace(k, v)
        argv.append(a)
    return argv


def _output_of(argv, out):
    """The output path in ``argv`` (a directory ``out`` or a file ``out.<suffix>``)."""
    return next(a for a in map(str, argv) if a.startswith(str(out)))


def test_every_command_that_writes_is_covered():
    from transient_mi.cli import command

    def walk(c, path=()):
        if hasattr(c, "commands"):
            for n, s in c.commands.items():
                yield from walk(s, path + (n,))
        else:
            yield " ".join(path), c

    writers = {name for name, c in walk(command())
               if any(p.name in ("out", "output") for p in c.params)}
    assert writers == set(COMMANDS), sorted(writers ^ set(COMMANDS))


@pytest.mark.parametrize("name", [n for n in COMMANDS if n != "dataset"])
def test_a_second_writer_is_refused_and_a_dead_writers_lock_is_taken_over(tmp_path, inputs, name):
    template, finish = COMMANDS[name]
    work = tmp_path / "w"
    work.mkdir()
    argv = _argv(template, inputs, work / "out")
    target = _output_of(argv, work / "out")
    owner = subprocess.Popen(["sleep", "300"])
    try:
        lock = _lock.lock_path(target)
        rec = dict(_lock.owner_record("transient-mi (the first run)"), pid=owner.pid,
                   start_ticks=_lock.process_start_ticks(owner.pid))
        lock.write_text(json.dumps(rec))
        before = lock.read_bytes()
        r = run_cli(*argv)
        assert r.code == 2, (r.code, r.err)
        lines = [ln for ln in r.err.splitlines() if ln.strip()]
        assert len(lines) == 1 and "another run is writing this output" in lines[0], r.err
        assert f"pid {owner.pid}" in lines[0] and "the first run" in lines[0] and "Traceback" not in r.err
        assert sorted(p.name for p in work.iterdir()) == [lock.name]  # nothing written
        assert lock.read_bytes() == before  # the first run's lock is untouched: it finishes undisturbed
    finally:
        owner.kill()
        owner.wait()
    if not finish:
        return
    # the first run died without releasing its lock: the next run takes it over and finishes
    r = run_cli(*argv)
    assert r.code == 0, r.err
    assert not lock.exists()
    assert (work / "out").exists() or any(p.name.startswith("out.") for p in work.iterdir())
    assert not [p.name for p in work.iterdir() if p.name.startswith(".")]


FLOCK_HOLDER = """
import fcntl, os, sys, time
fd = os.open(sys.argv[1], os.O_CREAT | os.O_RDWR, 0o666)
fcntl.flock(fd, fcntl.LOCK_EX)
print("held", flush=True)
time.sleep(300)
"""


def test_a_second_dataset_run_is_refused_while_the_first_holds_its_directory(tmp_path, inputs):
    """The dataset runner's lock is flock(2) on OUT/.dataset.lock (the kernel drops it when its holder dies, so a
    dead run's lock is never stale): a live holder refuses the second run in one line, which writes nothing."""
    import sys

    from transient_mi.dataset.runner import LOCK_NAME

    out = tmp_path / "out"
    out.mkdir()
    holder = subprocess.Popen([sys.executable, "-c", FLOCK_HOLDER, str(out / LOCK_NAME)], stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        r = run_cli(*_argv(COMMANDS["dataset"][0], inputs, out))
        assert r.code == 2, (r.code, r.err)
        lines = [ln for ln in r.err.splitlines() if ln.strip()]
        assert len(lines) == 1 and "another transient-mi dataset run is writing this directory" in lines[0], r.err
        assert sorted(p.name for p in out.iterdir()) == [LOCK_NAME]
    finally:
        holder.kill()
        holder.wait()
