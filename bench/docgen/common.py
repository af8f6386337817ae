"""What every generator shares: the records of a results folder, provenance lines, number formats."""

from __future__ import annotations

from pathlib import Path
import json


class Missing(Exception):
    """A record that the generator needs is not in bench/results/."""


class Records:
    """The JSON records of one results folder, loaded on demand."""

    def __init__(self, folder: Path):
        self.folder = folder
        self._cache: dict[str, dict] = {}

    def __call__(self, name: str) -> dict:
        if name not in self._cache:
            p = self.folder / f"{name}.json"
            if not p.is_file():
                raise Missing(name)
            self._cache[name] = json.loads(p.read_text())
        return self._cache[name]


def machine_line(rec: dict) -> str:
    """'Intel(R) Xeon(R) Processor, 2 cores, 23.6 GiB, load 4.3 -> 3.8'."""
    m = rec["machine"]
    load = ""
    if m.get("load_average_1min_start") is not None:
        load = f", 1-min load {m['load_average_1min_start']:.1f} -> {m['load_average_1min_end']:.1f}"
    return f"{m['cpu_model']}, {m['cores']} cores, {m['memory_gib']:g} GiB{load}"


def shown_command(rec: dict) -> str:
    """The record's command without its ``--note`` text (the note is quoted separately)."""
    import shlex

    words, out, skip = shlex.split(rec["command"]), [], False
    for w in words:
        if skip:
            skip = False
            continue
        if w == "--note":
            skip = True
            continue
        if not w.startswith("--note="):
            out.append(w)
    return shlex.join(out)


def provenance(rec: dict, *, short: bool = False) -> str:
    """Where a number comes from: file, command, date, machine (and the record's note)."""
    date = rec["date_utc"][:10]
    f = f"`bench/results/{rec['name']}.json`"
    if short:
        return f"{f}, {date}, {rec['machine']['cores']} cores"
    note = f" {rec['note'].rstrip('.')}." if rec.get("note") else ""
    return f"Source: {f} (`{shown_command(rec)}`, {date}; {machine_line(rec)}).{note}"


def not_measured(names: list[str], inline: bool) -> str:
    files = ", ".join(f"`bench/results/{n}.json`" for n in names)
    if inline:
        return f"(not yet re-measured: {files} missing)"
    return f"\n*Not yet re-measured: {files} missing (run the benchmark with `--save`).*\n"


def sci(n: float) -> str:
    """1000000 -> '1e6'."""
    m, e = f"{n:.0e}".split("e")
    return f"{m}e{int(e)}"


def g2(x: float) -> str:
    """Two significant digits, exponent without '+' and leading zeros: 3.2e6."""
    t = f"{x:.2g}"
    if "e" in t:
        m, e = t.split("e")
        t = f"{m}e{int(e)}"
    return t


def s(x: float) -> str:
    """Seconds with 3 significant digits."""
    return f"{x:.3g} s"


def _gb(mb: float) -> str:
    return f"{mb / 1024:.1f} GB"


def _own_provenance(rec: dict, name: str) -> str:
    """Provenance of a record written by bench_noise.py, bench_render_variance.py, noise_figure.py or
    bench_view.py (``bench/_record.as_record``: the script's machine fields kept)."""
    m = rec.get("machine", {})
    load = m.get("load_average_1_5_15") or m.get("load_average_at_end")
    load_txt = f", 1-min load {load[0]:.1f}" if load else ""
    return (f"Source: `bench/results/{name}.json` (`{rec['command'].strip()}`, {rec['date_utc'][:10]}; "
            f"{m.get('cpu_model') or m.get('cpu', '?')}, {m.get('cores', '?')} cores{load_txt}).")
