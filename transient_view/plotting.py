"""Small Bokeh helpers shared by the panels: image figures, HTML tables, status lines."""

from __future__ import annotations

import html

import numpy as np

__all__ = ["image_figure", "set_image", "facts_html", "Status", "robust_max"]


def robust_max(a: np.ndarray, q: float = 99.9) -> float:
    """The ``q``-th percentile of ``a`` (its maximum if that is 0), at least a tiny positive number."""
    a = np.asarray(a, dtype=np.float64)
    if a.size == 0:
        return 1.0
    hi = float(np.percentile(a, q))
    if not hi > 0:
        hi = float(a.max())
    return hi if hi > 0 else 1e-30


def image_figure(title: str, x_label: str, y_label: str, extent: tuple[float, float, float, float], *,
                 width: int = 330, height: int = 300, palette: str = "Inferno256", tools: str = "pan,wheel_zoom,reset",
                 colorbar_title: str | None = None, name: str | None = None):
    """A figure with one image glyph covering ``extent = (x0, x1, y0, y1)``; returns ``(figure, source, mapper)``."""
    from bokeh.models import ColorBar, ColumnDataSource, LinearColorMapper
    from bokeh.plotting import figure

    x0, x1, y0, y1 = extent
    fig = figure(title=title, width=width, height=height, x_range=(x0, x1), y_range=(y0, y1), tools=tools,
                 x_axis_label=x_label, y_axis_label=y_label, name=name, toolbar_location="above",
                 css_classes=[f"tmv-{name}"] if name else [])
    mapper = LinearColorMapper(palette=palette, low=0, high=1, nan_color="#202020")
    src = ColumnDataSource(data={"image": [np.zeros((1, 1), dtype=np.float32)], "x": [x0], "y": [y0],
                                 "dw": [x1 - x0], "dh": [y1 - y0]})
    fig.image(image="image", x="x", y="y", dw="dw", dh="dh", source=src, color_mapper=mapper)
    fig.add_layout(ColorBar(color_mapper=mapper, width=8, title=colorbar_title), "right")
    fig.grid.visible = False
    return fig, src, mapper


def set_image(src, mapper, img: np.ndarray, extent: tuple[float, float, float, float] | None = None,
              low: float | None = None, high: float | None = None) -> None:
    """Show ``img[rows, cols]`` (row 0 at the bottom) in an :func:`image_figure`, colour range ``low..high``."""
    a = np.ascontiguousarray(img, dtype=np.float32)
    data = {"image": [a]}
    if extent is not None:
        x0, x1, y0, y1 = extent
        data.update(x=[x0], y=[y0], dw=[x1 - x0], dh=[y1 - y0])
    else:
        data.update({k: src.data[k] for k in ("x", "y", "dw", "dh")})
    finite = a[np.isfinite(a)]
    lo = float(finite.min()) if low is None and finite.size else (0.0 if low is None else low)
    hi = robust_max(finite) if high is None else high
    if not hi > lo:
        hi = lo + 1e-30 if lo == 0 else lo + abs(lo) * 1e-6
    mapper.update(low=lo, high=hi)
    src.data = data


def facts_html(rows: list[tuple[str, str]], title: str | None = None) -> str:
    """A small two-column HTML table (escaped)."""
    head = f"<b>{html.escape(title)}</b>" if title else ""
    body = "".join(f"<tr><td style='padding-right:1em;color:#555'>{html.escape(k)}</td>"
                   f"<td>{html.escape(v)}</td></tr>" for k, v in rows)
    return f"{head}<table style='font-size:12px;border-collapse:collapse'>{body}</table>"


class Status:
    """A status line (a Bokeh ``Div``) whose text ends in an update counter, so tests and benchmarks can
    tell when the result of a change has reached the browser: ``"<name> #<n>: <message>"``."""

    def __init__(self, name: str):
        from bokeh.models import Div

        self.name = name
        self.n = 0
        self.div = Div(text=f"{name} #0: waiting", name=f"{name}_status", styles={"font-size": "12px"})

    def done(self, message: str) -> None:
        self.n += 1
        self.div.text = f"{self.name} #{self.n}: {html.escape(message)}"

    def error(self, message: str) -> None:
        self.n += 1
        self.div.text = f"{self.name} #{self.n}: <span style='color:#b00'>{html.escape(message)}</span>"
