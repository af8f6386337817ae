"""The local web server: a Bokeh server for the page plus a read-only route for the viewed files.

Security: it binds to ``127.0.0.1`` unless told otherwise, accepts page connections
(websockets) only from the address it serves (from any origin when bound to a network address
with ``--host``, which the command warns about), and serves files only from the
viewed path under ``/files/`` (:meth:`~transient_view.data.Library.resolve`
refuses ``..``, absolute names and symbolic links that leave it, with 403). Nothing
is ever written.
"""

from __future__ import annotations

import ipaddress
import mimetypes
import socket

from .data import Library

__all__ = ["make_server", "free_port", "is_loopback"]


def is_loopback(host: str) -> bool:
    """True for ``localhost`` and loopback addresses (127.0.0.0/8, ::1)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def free_port(host: str) -> int:
    """A TCP port that is free on ``host`` now (the OS's choice)."""
    fam = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(fam, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def _file_handler(lib: Library):
    import tornado.web

    class FileHandler(tornado.web.RequestHandler):
        """GET/HEAD ``/files/<name>``: a file of the viewed path, read-only; anything else is 403."""

        def _send(self, name: str, body: bool) -> None:
            try:
                p = lib.resolve(name)
            except PermissionError:
                raise tornado.web.HTTPError(403, reason="outside the viewed path") from None
            ctype = mimetypes.guess_type(p.name)[0] or "application/octet-stream"
            self.set_header("Content-Type", ctype)
            self.set_header("X-Content-Type-Options", "nosniff")
            if body:
                self.write(p.read_bytes())

        def get(self, name: str) -> None:
            self._send(name, True)

        def head(self, name: str) -> None:
            self._send(name, False)

    return FileHandler


def make_server(lib: Library, host: str = "127.0.0.1", port: int = 5006):
    """A started-but-not-running :class:`bokeh.server.server.Server` for ``lib`` (``port=0``: a free port).

    Run it with ``server.io_loop.start()``; stop with ``server.stop()``.
    """
    from bokeh.application import Application
    from bokeh.application.handlers.function import FunctionHandler
    from bokeh.server.server import Server

    from .app import make_document
    # Import what the first page needs now, before the address is printed, not on the first request.
    import bokeh.plotting  # noqa: F401

    from . import capture_panel, detector_panel, recon_panel  # noqa: F401

    if port == 0:
        port = free_port(host)
    if is_loopback(host):
        origins = [f"{host}:{port}", f"localhost:{port}", f"127.0.0.1:{port}"]
    else:
        # Bound to a network address on purpose (--host): browsers elsewhere reach it under names this
        # machine cannot know, so any origin may open the page; the command warns that the data is exposed.
        origins = ["*"]
    app = Application(FunctionHandler(make_document(lib)))
    server = Server({"/": app}, address=host, port=port, allow_websocket_origin=sorted(set(origins)),
                    extra_patterns=[(r"/files/(.*)", _file_handler(lib))], num_procs=1,
                    check_unused_sessions_milliseconds=2000, unused_session_lifetime_milliseconds=5000)
    _serve_only_the_bokehjs_we_use(server)
    server.start()
    return server


#: BokehJS bundles the page loads. A Bokeh server page loads every bundle by default because it cannot
#: know the document in advance; the viewer draws no LaTeX (``bokeh-mathjax``, 1.8 MB) and no WebGL
#: (``bokeh-gl``), so the first page leaves them out (tables stay: the reconstruction tab's metrics).
BOKEHJS_COMPONENTS = ["bokeh", "bokeh-widgets", "bokeh-tables"]


def _serve_only_the_bokehjs_we_use(server) -> None:
    tornado_app = server._tornado
    default = tornado_app.resources

    def resources(absolute_url=None):
        return default(absolute_url).clone(components=list(BOKEHJS_COMPONENTS))

    tornado_app.resources = resources
