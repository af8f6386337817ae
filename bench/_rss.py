"""Memory of this process, the one measure every benchmark and peer worker reports (Linux ``/proc``).

Peak memory is ``VmHWM`` from ``/proc/self/status``: the process's own peak resident set since it
started or since :func:`reset_peak_rss` (unlike ``ru_maxrss`` it does not carry a parent's peak over
fork + exec). Standard library only and no ``from __future__`` syntax beyond Python 3.7, so the peer
workers (``_mitransient_worker.py``, ``_ytal_runner.py``), which run under the peers' own interpreters and
import nothing of transient-mi, import it from this folder too.
"""


def _status_kib(key):
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith(key + ":"):
                return int(line.split()[1])
    raise RuntimeError(f"{key} not found in /proc/self/status (Linux only)")


def peak_rss_mb():
    """Peak resident set of this process in MiB (``VmHWM``; Linux)."""
    return _status_kib("VmHWM") / 1024.0


def rss_mb():
    """Current resident set of this process in MiB (``VmRSS``; Linux)."""
    return _status_kib("VmRSS") / 1024.0


def reset_peak_rss():
    """Reset this process's ``VmHWM`` to its current resident set (``clear_refs`` 5); False if refused."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False
