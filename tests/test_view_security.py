"""The viewer's server serves the viewed folder and nothing else (transient_view.server, docs/reliability.md).

A real ``transient-mi view`` process (the Mitsuba-free front door) is asked, over raw HTTP, for files outside
its folder every way a browser or a hostile page could: ``..`` plain, percent-encoded and double-encoded,
backslashes, NUL bytes, absolute paths, symbolic links (to a file and to a directory) that leave the folder,
and oversized requests. Every such request under ``/files/`` is answered 403 or 400 (an oversized one is refused
or dropped) and no byte of the outside file is served; the server keeps serving afterwards. It listens on
127.0.0.1 unless ``--host`` says otherwise.
"""

from __future__ import annotations

import http.client
import socket
import subprocess
import sys
from pathlib import Path

import psutil
import pytest

from view_helpers import ideal_capture

ROOT = Path(__file__).resolve().parents[1]
MARKER = b"SECRET-OUTSIDE-THE-VIEWED-FOLDER"


def _start(path: Path, *extra):
    code = "import sys; from transient_cli import main; sys.exit(main())"
    proc = subprocess.Popen([sys.executable, "-c", code, "view", str(path), "--no-browser", "--port", "0", *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT)
    line = proc.stdout.readline()
    if not line.startswith("serving at "):
        proc.kill()
        raise AssertionError(f"server did not start: {line!r} {proc.stderr.read()}")
    return proc, line.split()[2]


def _stop(proc) -> str:
    proc.terminate()
    try:
        _, err = proc.communicate(timeout=10)
    except subprocess.TimeoutExpired:
        proc.kill()
        _, err = proc.communicate()
    return err


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    base = tmp_path_factory.mktemp("security")
    (base / "secret.txt").write_bytes(MARKER)
    (base / "outside").mkdir()
    (base / "outside" / "secret.txt").write_bytes(MARKER)
    root = base / "served"
    root.mkdir()
    ideal_capture(root / "ideal", pixels=4, spots=1, n_bins=16)
    (root / "escape.txt").symlink_to(base / "secret.txt")
    (root / "escdir").symlink_to(base / "outside", target_is_directory=True)
    (root / "ideal" / "inside_link.json").symlink_to(root / "ideal" / "manifest.json")  # a link that stays in
    proc, url = _start(root)
    yield root, base, url
    _stop(proc)


def _request(url: str, raw_path: str, method: str = "GET", headers=None, body=None):
    host, port = url.split("//")[1].rstrip("/").split(":")
    c = http.client.HTTPConnection(host, int(port), timeout=20)
    try:
        c.putrequest(method, raw_path, skip_host=False, skip_accept_encoding=True)
        for k, v in (headers or {}).items():
            c.putheader(k, v)
        c.endheaders(body)
        r = c.getresponse()
        return r.status, r.read()
    except (ConnectionError, http.client.RemoteDisconnected, socket.timeout):
        return None, b""  # dropped without an answer: nothing served
    finally:
        c.close()


OUTSIDE = [
    "/files/../secret.txt", "/files/../../../../etc/passwd",
    "/files/%2e%2e/secret.txt", "/files/ideal/%2e%2e/%2e%2e/secret.txt", "/files/..%2fsecret.txt",
    "/files/%252e%252e/secret.txt", "/files/%252e%252e%252fsecret.txt", "/files/ideal/%25%32%65%25%32%65/x",
    "/files/..%5csecret.txt", "/files/ideal%5c..%5c..%5csecret.txt",
    "/files/ideal/%00manifest.json", "/files/ideal/manifest.json%00", "/files/%00../secret.txt",
    "/files//etc/passwd", "/files/%2fetc%2fpasswd", "/files/%2F{secret}", "/files/{secret}",
    "/files/escape.txt", "/files/escdir/secret.txt", "/files/escdir/../secret.txt",
    "/files/ideal", "/files/", "/files/nonexistent.json",
]


def test_nothing_outside_the_folder_is_served(served):
    root, base, url = served
    status, body = _request(url, "/files/ideal/manifest.json")
    assert status == 200 and body == (root / "ideal" / "manifest.json").read_bytes()
    status, body = _request(url, "/files/ideal/inside_link.json")  # a link inside the folder is fine
    assert status == 200 and body == (root / "ideal" / "manifest.json").read_bytes()
    secret = str(base / "secret.txt").lstrip("/")
    for raw in OUTSIDE:
        raw = raw.replace("{secret}", secret)
        for method in ("GET", "HEAD"):
            status, body = _request(url, raw, method)
            assert status in (400, 403), (method, raw, status)
            assert MARKER not in body and b"root:" not in body, (method, raw)
    for raw in ("/static/../../../../etc/passwd", "/..%2f..%2fsecret.txt", "/%2e%2e/secret.txt"):
        status, body = _request(url, raw)  # outside /files/: Bokeh's own routes, which serve none of ours
        assert status in (400, 403, 404), (raw, status)
        assert MARKER not in body
    print(f"viewer: {2 * len(OUTSIDE) + 3} requests for files outside the folder refused")


def test_oversized_requests_are_refused_and_the_server_keeps_serving(served):
    root, _, url = served
    huge_path = "/files/" + "a/" * 40_000 + "manifest.json"  # 80 kB request line (tornado's limit: 64 kB)
    status, body = _request(url, huge_path)
    assert status in (None, 400, 403, 414, 431), status
    status, _ = _request(url, "/files/ideal/manifest.json", headers={"X-Big": "b" * 100_000})
    assert status in (None, 400, 431), status
    status, _ = _request(url, "/files/ideal/manifest.json", "POST", headers={"Content-Length": str(10 ** 12)})
    assert status in (None, 400, 403, 405, 413), status
    status, body = _request(url, "/files/ideal/manifest.json")
    assert status == 200 and body == (root / "ideal" / "manifest.json").read_bytes()


def _listening(pid: int) -> set[str]:
    return {c.laddr.ip for c in psutil.Process(pid).net_connections(kind="tcp") if c.status == psutil.CONN_LISTEN}


def test_listens_on_127_0_0_1_unless_host_says_otherwise(served, tmp_path):
    root, _, _ = served
    proc, url = _start(root)
    try:
        assert url.startswith("http://127.0.0.1:")
        assert _listening(proc.pid) == {"127.0.0.1"}
    finally:
        err = _stop(proc)
    assert "warning" not in err
    proc, url = _start(root, "--host", "0.0.0.0")
    try:
        assert _listening(proc.pid) == {"0.0.0.0"}
    finally:
        err = _stop(proc)
    assert "warning: listening on 0.0.0.0: anyone who can reach this machine can see the data" in err
