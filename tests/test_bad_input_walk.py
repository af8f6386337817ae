"""Every option of every command, walked from the command line's own definitions, with values it must refuse.

For each command of ``transient-mi`` (typer's click tree) and each of its parameters, the value the
parameter's type allows is replaced by ones it does not: for numbers a word, nothing, a fraction (whole
numbers), NaN, infinities and an overflowing 1e400; for words nothing; for files that the command reads corrupt
files of each format the project reads (EXR, manifest JSON, HDF5, .mat, PLY, XML, YAML), an empty file, a
directory and a missing path; for outputs an unwritable place and an existing file where a directory goes. Every
case must end with exactly one line ``error: ...`` naming the parameter or the value, exit status 2, no traceback
and nothing written. The commands run in this process (no Mitsuba import per case); the few that would start long
work once their input is accepted (render, demo, study, dataset, fit, view) stop at the point where they would
take their output lock or start the server: reaching it with a bad value counts as accepted, a failure.

The counts (cases walked, refused in one line, accepted) are printed in the test summary
(``pytest_terminal_summary`` in tests/conftest.py) and stated in the assertion message.
"""

from __future__ import annotations

import shutil
import time
import typing
from pathlib import Path

import numpy as np
import pytest

from detector_helpers import make_ideal_capture
from fault_helpers import ROOT, run_cli

#: Collected by the walk, printed by tests/conftest.py's pytest_terminal_summary.
REPORT: dict[str, object] = {}

NUMBER_BAD = ["abc", "", "nan", "inf", "-inf", "1e400"]
WHOLE_BAD = ["abc", "", "1.5", "nan", "inf", "1e400"]
WORD_BAD = [""]
#: Huge but finite: a command may accept it (and then must finish, exit 0) or refuse it in one line, never crash.
HUGE = "1e12"
#: Accepted with 1e12 and then slow (about 12 s each: 1e12 counts per second saturate every bin), so walked without
#: the huge value to keep CI fast; their other bad values are walked.
SLOW_HUGE = {(("detect",), "--dark-count-rate-cps"), (("detect",), "--ambient-rate-cps")}
#: free-form words whose refusal needs the outside world (a host to listen on, a scheduler to reach)
FREE_WORDS = {("view", "--host"), ("dataset", "--scheduler"), ("render", "--variant"), ("info", "--variant")}

NLOS_D = ["-D", "width=2", "-D", "height=2", "-D", "spots_x=1", "-D", "spots_y=1", "-D", "n_bins=8",
          "-D", "bin_width_ps=256"]
SPEC = """\
scene: cornell_box
seed: 1
spp: 1
defines: {width: 2, height: 2, n_bins: 8, bin_width_ps: 600}
grid:
  max_depth: [2, 3]
"""


#: Corrupt files whose error names the entry inside the file (the spec's key and value) instead of the file.
INSIDE = {"wrong_scene.yaml": ("scene: 'no_such_scene'",)}


class Reached(BaseException):
    """The command accepted its input and was about to take its output lock / start serving."""


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    """Valid inputs, and corrupt files of each format, in a directory of their own."""
    d = tmp_path_factory.mktemp("walk_inputs")
    data = np.zeros((2, 3, 3, 24), np.float32)
    data[..., 10:13] = 1e-3
    make_ideal_capture(d / "ideal", data, bin_width_ps=64.0)
    from spad_detector import detect_stack

    r = run_cli("render", ROOT / "scenes" / "nlos_tilted_plane.xml", "-o", d / "rendered", *NLOS_D, "--spp", "8",
                "-D", "estimator=monte_carlo")
    assert r.code == 0, r.err  # fit renders the capture's own scene again: a rendered capture
    detect_stack(d / "rendered", d / "counts", pulses=1000, seed=0, progress=False, warn=lambda line: None)
    (d / "spec.yaml").write_text(SPEC)
    f = {"ideal": d / "ideal", "counts": d / "counts", "spec": d / "spec.yaml",
         "scene": ROOT / "scenes" / "nlos_point_targets.xml"}
    bad = {}

    def broken_capture(name, edit):
        p = d / name
        shutil.copytree(d / "ideal", p)
        edit(p)
        bad[name] = p

    broken_capture("manifest_not_json", lambda p: (p / "manifest.json").write_text("{"))
    broken_capture("manifest_list", lambda p: (p / "manifest.json").write_text("[]"))
    broken_capture("manifest_nan_bins", lambda p: (p / "manifest.json").write_text(
        (p / "manifest.json").read_text().replace('"n_bins": 24', '"n_bins": NaN')))
    broken_capture("exr_truncated", lambda p: (p / "spot_00001.exr").write_bytes(
        (p / "spot_00001.exr").read_bytes()[:300]))
    broken_capture("exr_garbage", lambda p: (p / "spot_00000.exr").write_bytes(b"not an exr file" * 40))
    broken_capture("exr_missing", lambda p: (p / "spot_00001.exr").unlink())
    (d / "empty_dir").mkdir()
    bad["empty_dir"] = d / "empty_dir"
    from recon.io.ytal import write_ytal
    from recon import load_capture

    write_ytal(load_capture(d / "ideal"), d / "full.h5")
    h5 = (d / "full.h5").read_bytes()
    for name, content in {"truncated.h5": h5[: len(h5) // 2], "text.h5": b"plain text\n" * 30,
                          "empty.h5": b"", "text.mat": b"hello, this is a text file\n" * 12, "empty.mat": b"",
                          "garbage.ply": b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n",
                          "empty.ply": b"", "garbage.json": b"[1, 2", "garbage.xml": b"<scene version='3.0.0'><shape",
                          "empty.xml": b"", "html.xml": b"<html><body/></html>",
                          "unknown_plugin.xml": b"<scene version='3.0.0'><shape type='nonexistent_shape'/></scene>",
                          "garbage.yaml": b"scene: [unclosed\n", "empty.yaml": b"", "list.yaml": b"- a\n- b\n",
                          "wrong_scene.yaml": SPEC.replace("cornell_box", "no_such_scene").encode(),
                          "irf_garbage.csv": b"a,b\nx,y\n"}.items():
        (d / name).write_bytes(content)
        bad[name] = d / name
    bad["missing"] = d / "does_not_exist"
    f["bad"] = bad
    return f


def _capture_inputs(f, *, h5=True, mat=False):
    names = ["manifest_not_json", "manifest_list", "manifest_nan_bins", "exr_truncated", "exr_garbage",
             "exr_missing", "empty_dir", "missing"]
    if h5:
        names += ["truncated.h5", "text.h5", "empty.h5"]
    if mat:
        names += ["text.mat", "empty.mat"]
    return [f["bad"][n] for n in names]


def baselines(f) -> dict[tuple[str, ...], list[str]]:
    """A valid (tiny) invocation of each command; ``{out}`` is replaced by a fresh output path."""
    return {
        ("render",): ["render", f["scene"], "-o", "{out}", *NLOS_D, "--spp", "1"],
        ("detect",): ["detect", f["ideal"], "-o", "{out}", "--pulses", "100"],
        ("recon",): ["recon", f["ideal"], "-o", "{out}", "--voxels", "4", "--no-plots"],
        ("demo",): ["demo", "--quick", "-o", "{out}"],
        ("study", "photon-budget"): ["study", "photon-budget", "-o", "{out}", "--quick"],
        ("study", "array-size"): ["study", "array-size", "-o", "{out}", "--quick", "--arrays", "2"],
        ("study", "methods"): ["study", "methods", "-o", "{out}", "--quick", "--arrays", "2"],
        ("dataset",): ["dataset", f["spec"], "-o", "{out}"],
        ("fit",): ["fit", f["counts"], "-o", "{out}", "--model", "patches", "--bin-width-ps", "256"],
        ("export",): ["export", f["ideal"], "{out}.h5", "--to", "ytal"],
        ("video",): ["video", f["ideal"], "-o", "{out}.gif"],
        ("view",): ["view", f["ideal"], "--no-browser", "--port", "0"],
        ("scene-mesh",): ["scene-mesh", f["scene"], "-o", "{out}.ply"],
        ("mannequin",): ["mannequin", "-o", "{out}.ply", "--detail", "8"],
        ("info",): ["info"],
    }


def _annotation(param):
    td = getattr(param, "type_descriptor", None)
    ann = getattr(td, "annotation", None)
    if ann is None:  # older typer: click's own types
        name = getattr(getattr(param, "type", None), "name", "text")
        return {"integer": int, "float": float, "path": Path, "boolean": bool}.get(name, str)
    while typing.get_origin(ann) in (typing.Union, list, typing.List) or str(typing.get_origin(ann)) == \
            "<class 'types.UnionType'>":
        ann = next(a for a in typing.get_args(ann) if a is not type(None))
    return ann


#: (command, parameter) -> the corrupt or wrong inputs to give it (parameters that read files)
def _file_cases(f, cmd, name):
    bad = f["bad"]
    xml = [bad[n] for n in ("garbage.xml", "empty.xml", "html.xml", "unknown_plugin.xml", "missing")] + \
        [bad["empty_dir"]]
    mesh = [bad[n] for n in ("garbage.ply", "empty.ply", "garbage.json", "missing")] + [bad["empty_dir"]]
    table = {
        (("render",), "scene"): xml, (("scene-mesh",), "scene"): xml,
        (("study", "photon-budget"), "scene"): xml, (("study", "array-size"), "scene"): xml,
        (("study", "methods"), "scene"): xml,
        (("detect",), "ideal"): _capture_inputs(f, h5=False),
        (("detect",), "irf_file"): [bad["irf_garbage.csv"], bad["missing"], bad["empty_dir"]],
        (("recon",), "capture"): _capture_inputs(f, mat=True),
        (("export",), "capture"): _capture_inputs(f, mat=True),
        (("fit",), "capture"): _capture_inputs(f, h5=False),
        (("video",), "capture"): _capture_inputs(f),
        (("view",), "path"): [bad[n] for n in ("truncated.h5", "text.h5", "empty.h5", "empty_dir", "missing",
                                               "text.mat")],
        (("dataset",), "spec"): [bad[n] for n in ("garbage.yaml", "empty.yaml", "list.yaml", "wrong_scene.yaml",
                                                   "missing", "empty_dir")],
    }
    for c in (("recon",), ("view",), ("study", "photon-budget"), ("study", "array-size"), ("study", "methods")):
        table[(c, "ground_truth")] = mesh
    return table.get((cmd, name))


OUTPUT_PARAMS = {"out", "output"}


def _cases(f):
    """Yield ``(command, the parameter's names, argv, value)`` for every bad value of every parameter."""
    from transient_mi.cli import command

    base = baselines(f)

    def walk(c, path=()):
        if hasattr(c, "commands"):
            for n, s in sorted(c.commands.items()):
                yield from walk(s, path + (n,))
        else:
            yield path, c

    for path, cmd in walk(command()):
        assert path in base, f"no baseline for the command {' '.join(path)}: add one to test_bad_input_walk.py"
        argv = [str(a) for a in base[path]]
        for p in cmd.params:
            if p.name == "help" or getattr(p, "is_flag", False) or not p.expose_value:
                continue
            ann = _annotation(p)
            is_opt = getattr(p, "param_type_name", "") == "option"
            flag = p.opts[-1] if is_opt else None
            label = flag or p.name.upper()
            if p.name in OUTPUT_PARAMS:
                given = next(x for x in argv if x.startswith("{out}"))
                suffix = given[len("{out}"):]  # "" for an output directory, ".gif" etc. for an output file
                values = ["/proc/transient-mi-walk/out" + suffix,  # a place nobody can write into
                          str(f["bad"]["empty_dir"] if suffix else f["bad"]["text.h5"])]  # a dir / a file there
            elif ann is Path:
                values = _file_cases(f, path, p.name)
                if values is None:
                    continue
                values = [str(v) for v in values]
            elif ann is int:
                values = WHOLE_BAD + [HUGE]
            elif ann is float:
                values = NUMBER_BAD + ([] if (path, flag) in SLOW_HUGE else [HUGE])
            elif ann is str:
                if (path[0], flag) in FREE_WORDS:
                    continue
                values = WORD_BAD + (["=novalue" if p.name == "define" else "definitely-not-allowed"])
            else:
                continue
            names = [*p.opts, p.name, p.name.upper()]
            for v in values:
                yield path, names, _with(argv, p, flag, v), v


def _with(argv, p, flag, value):
    """``argv`` with parameter ``p`` set to ``value`` (replacing the baseline's value, if any)."""
    a = list(argv)
    if flag is None:  # a positional argument: the baseline's positional of that name is the first non-option
        idx = _positional_index(a, p)
        if idx is None:
            return a + [value]
        a[idx] = value
        return a
    for o in p.opts:
        if o in a and o not in ("-D", "--define"):
            i = a.index(o)
            a[i + 1] = value
            return a
    return a + [flag, value]


def _positional_index(a, p):
    # baselines put the command's positional arguments right after the command words
    words = 2 if a[0] == "study" else 1
    if p.name == "output" and a[0] == "export":
        return words + 1
    return words if len(a) > words and not a[words].startswith("-") else None


#: Commands that start long work once they take their output lock (the others run: their work is tiny here).
LONG = {"render", "demo", "study", "dataset"}
_current = {"command": None}


@pytest.fixture
def stop_before_work(monkeypatch):
    """Make the long commands stop where they would take their output lock (or start serving)."""
    import transient_core.lock as lock
    import transient_view.server as server

    def reached(*a, **k):
        raise Reached()

    acquire = lock.acquire

    def acquire_or_stop(*a, **k):
        if _current["command"] in LONG:
            raise Reached()
        return acquire(*a, **k)

    monkeypatch.setattr(lock, "acquire", acquire_or_stop)
    monkeypatch.setattr(server, "make_server", reached)
    import transient_mi.dataset.runner as runner

    monkeypatch.setattr(runner, "DaskConnection", reached)
    import transient_mi.fit.api as fit_api  # fit checks its capture under the lock: stop where it would start

    monkeypatch.setattr(fit_api, "_backprojection", reached)


def _run(argv, work: Path):
    _current["command"] = argv[0]
    out = work / "out"
    argv = [a.replace("{out}", str(out)) for a in argv]
    try:
        r = run_cli(*argv)
    except Reached:
        return None, argv
    return r, argv


def _written(work: Path) -> list[str]:
    return sorted(str(p.relative_to(work)) for p in work.rglob("*"))


def test_baselines_are_accepted(files, tmp_path, stop_before_work):
    """Each command's baseline is valid: so a refusal in the walk is caused by the bad value alone."""
    for path, argv in baselines(files).items():
        r, shown = _run([str(a) for a in argv], tmp_path)
        assert r is None or r.code == 0, (shown, r.code, r.err)
        for p in tmp_path.iterdir():
            shutil.rmtree(p) if p.is_dir() else p.unlink()


def test_every_option_refuses_bad_values_in_one_line(files, tmp_path, stop_before_work):
    cases = list(_cases(files))
    failures = []
    per_command: dict[str, int] = {}
    accepted_huge: list[str] = []
    took: list[tuple[float, str]] = []
    for path, names, argv, value in cases:
        label = names[0] if names[0].startswith("-") else names[-1]
        work = tmp_path / "w"
        work.mkdir()
        t0 = time.perf_counter()
        r, shown = _run(argv, work)
        took.append((time.perf_counter() - t0, " ".join(shown[:1]) + f" {label}={value!r}"))
        why = None
        if value == HUGE and (r is None or r.code == 0):
            # accepted a huge value: allowed (the command did its work, or would start it)
            accepted_huge.append(f"{' '.join(path)} {label}")
        elif r is None:
            why = "accepted (would start the work)"
        elif r.code != 2:
            why = f"exit {r.code}" + (" with a traceback" if "Traceback" in r.err else "")
        else:
            lines = [ln for ln in r.err.splitlines() if ln.strip()]
            named = [*names, Path(value).name if value else None, *INSIDE.get(Path(value).name, ())]
            if "Traceback" in r.err or len(lines) != 1 or not lines[0].startswith("error: "):
                why = "not one error line"
            elif not any(n and n in lines[0] for n in named):
                why = "the line names neither the parameter nor the value"
            elif _written(work):
                why = f"wrote {_written(work)}"
        if why:
            failures.append(f"{' '.join(path)} {label}={value!r}: {why}: {(r.err.strip() if r else '')[-300:]}")
        per_command[" ".join(path)] = per_command.get(" ".join(path), 0) + 1
        shutil.rmtree(work)
    refused = len(cases) - len(failures) - len(accepted_huge)
    REPORT.update(walked=len(cases), handled=len(cases) - len(failures), refused=refused, commands=len(per_command),
                  per_command=per_command, accepted_huge=accepted_huge)
    summary = (f"bad-input walk: {len(cases)} bad values over {len(per_command)} commands: {refused} refused in "
               f"one line, {len(accepted_huge)} huge values accepted (run to the end, or up to the work), "
               f"{len(failures)} failures")
    print(summary)
    print("slowest cases:", sorted(took, reverse=True)[:8])
    assert len(cases) > 300, summary
    assert not failures, summary + ":\n" + "\n".join(failures)
