"""The viewer's page: a chooser of what to show under the root path, and three tabs
(capture, detector, reconstruction) built from the panels.

One document per browser tab; the detector and reconstruction tabs compute on first
being opened, so the first page appears without waiting for them.
"""

from __future__ import annotations

import html
from pathlib import Path

from .data import CaptureData, Library

__all__ = ["make_document"]

TAB_NAMES = ("Capture", "Detector", "Reconstruction")


def _message(text: str, name: str):
    from bokeh.models import Div

    return Div(text=f"<p style='font-size:14px'>{html.escape(text)}</p>", name=name, width=700)


def _files_links(lib: Library, p: Path) -> str:
    """Links to the files a person may want to open (served read-only under ``/files/``)."""
    if not p.is_dir():
        return ""
    names = [n for n in ("manifest.json", "preview.png", "recon.json", "metrics.json", "projections.png",
                         "depth.png") if (p / n).is_file()]
    names += sorted(f.name for f in p.glob("*.png") if f.name not in names)[:6]
    links = " ".join(f"<a href='files/{html.escape(lib.label(p / n))}' target='_blank'>{html.escape(n)}</a>"
                     for n in names)
    return f"files: {links}" if links else ""


def _query(doc, key: str) -> str | None:
    """The query argument ``key`` of the page's address, if any."""
    try:
        vals = doc.session_context.request.arguments.get(key)
    except AttributeError:
        return None
    return vals[0].decode("utf-8", "replace") if vals else None


class Page:
    """The state of one browser tab."""

    def __init__(self, lib: Library, doc):
        from bokeh.layouts import column, row
        from bokeh.models import CustomJS, Div, Select

        self.lib, self.doc = lib, doc
        self.items = [("capture", p) for p in lib.captures] + [("recon", p) for p in lib.recons]
        labels = [f"{kind}: {lib.label(p)}" for kind, p in self.items]
        chosen = _query(doc, "show")
        i = labels.index(chosen) if chosen in labels else 0
        self.chooser = Select(title="show", value=labels[i], options=labels, width=520, name="item_select")
        # Another item is another page (?show=...): a bookmarkable address, and one item per session.
        self.chooser.js_on_change("value", CustomJS(code="window.location.search = '?show=' + "
                                                         "encodeURIComponent(cb_obj.value)"))
        self.links = Div(text="", name="file_links")
        self.holder = column(Div(text=""), name="tabs_holder")
        self.panels = {}
        title = Div(text=f"<h2 style='margin:4px 0'>transient-mi view</h2><span style='color:#555'>"
                         f"{html.escape(str(lib.root))} (read-only)</span>")
        doc.add_root(column(title, row(self.chooser, self.links), self.holder, name="page"))
        doc.title = f"transient-mi view: {lib.root.name}"
        doc.on_session_destroyed(lambda ctx: self._stop())
        self.show(i)

    def _stop(self) -> None:
        cap = self.panels.get("capture")
        if cap is not None and hasattr(cap, "stop"):
            cap.stop()

    def show(self, i: int) -> None:
        """Build the three tabs for item ``i``."""
        from bokeh.models import TabPanel, Tabs

        from transient_core.errors import UserInputError

        self._stop()
        kind, p = self.items[i]
        self.panels = {}
        self.links.text = _files_links(self.lib, p)
        capture_path = p if kind == "capture" else self.lib.recon_capture(p)
        children = {}
        data = None
        try:
            if capture_path is not None:
                from .capture_panel import CapturePanel

                data = CaptureData(capture_path)
                self.panels["capture"] = CapturePanel(data, self.doc)
                children["Capture"] = self.panels["capture"].layout
            else:
                children["Capture"] = _message("this reconstruction does not name a capture inside the viewed path",
                                               "capture_unavailable")
            children["Detector"] = self._detector(data)
            children["Reconstruction"] = self._recon(kind, p, data)
        except (UserInputError, OSError, ValueError, KeyError) as e:
            msg = _message(f"cannot show {self.lib.label(p)}: {e}", "load_error")
            for name in TAB_NAMES:
                children.setdefault(name, msg if name == "Capture" else _message("(see the Capture tab)", "x"))
        # Panels are built and computed when their tab is first opened (a lighter first page).
        self._builders = {n: c for n, c in children.items() if callable(c)}
        for n in self._builders:
            children[n] = _message("opening...", f"{n.lower()}_placeholder")
        self.tabs = Tabs(tabs=[TabPanel(child=children[n], title=n) for n in TAB_NAMES], name="tabs")
        self.tabs.on_change("active", lambda a, o, n: self.open_tab(TAB_NAMES[n]))
        self.holder.children = [self.tabs]

    def _detector(self, data):
        if data is None:
            return _message("no capture: nothing to detect", "detector_unavailable")
        ideal = data.ideal_source(self.lib)
        if ideal is None:
            why = ("a camera capture (transient video) holds radiance, not photons per pulse"
                   if not data.has_wall else
                   "this counts capture's ideal capture (its manifest's source_ideal) is not inside the viewed "
                   "path; view the ideal capture to simulate the detector")
            return _message(f"The detector panel needs an ideal NLOS capture: {why}.", "detector_unavailable")
        from .detector_panel import DetectorPanel

        return lambda: DetectorPanel(ideal, self.doc)

    def _recon(self, kind, p, data):
        from .recon_panel import ReconPanel

        stored = None
        bounds = None
        if kind == "recon":
            from recon.output import load_volume

            stored = load_volume(p)
            # the stored grid's faces, rounded to a nanometre (a face on the wall may come back as -3e-18)
            bounds = tuple(0.0 if abs(v) < 1e-9 else round(v, 12) for v in stored.grid.bounds)
        capture = data.capture if data is not None else None
        if capture is None and stored is None:
            return _message("A camera capture (transient video) has no relay wall: nothing to reconstruct.",
                            "recon_unavailable")
        gt = self.lib.ground_truth_for(p if kind == "recon" else data.path)
        if gt is None and data is not None:
            gt = self.lib.ground_truth_for(data.path)
        return lambda: ReconPanel(capture, self.doc, stored=stored, ground_truth=gt, bounds=bounds)

    def open_tab(self, name: str) -> None:
        """What opening tab ``name`` does: build its panel on first opening, then compute it once."""
        key = {"Detector": "detector", "Reconstruction": "recon"}.get(name)
        if key is None:
            return
        builder = self._builders.pop(name, None)
        if builder is not None:
            self.panels[key] = builder()
            from bokeh.models import TabPanel

            panels = list(self.tabs.tabs)  # a new list: BokehJS rebuilds the tab's view
            panels[TAB_NAMES.index(name)] = TabPanel(child=self.panels[key].layout, title=name)
            self.tabs.tabs = panels
        panel = self.panels.get(key)
        if panel is not None and not panel.computed:
            panel.update()


def make_document(lib: Library):
    """A Bokeh application function ``f(doc)`` that builds the page for ``lib``."""

    def build(doc):
        Page(lib, doc)

    return build
