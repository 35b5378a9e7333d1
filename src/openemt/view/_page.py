"""The live view's page: one Bokeh document per browser tab, refreshed by a periodic callback
from :meth:`openemt.view.LiveFeed.snapshot`.

Panels (``?panel=NAME`` shows one alone): ``carriers`` (per carrier: drive and sensor level,
coupling level, SNR, quadrature), ``spectrum`` (per channel), ``coupling`` (the latest coupling
matrix), ``sensors`` (per sensor: status, quadrature ratio, residual, pose) and ``trail`` (the
positions of the last seconds, three projections). Every value shown lives in a named
``ColumnDataSource`` (``carriers``, ``spectrum``, ``coupling``, ``sensors``, ``trail`` (per
sensor a ``trail`` line and its ``latest`` position, a dot), ``header``, ``collect``,
``dwells``), which a test reads back through Bokeh's document in the browser; the HTML of the
header line and the tables goes through the source ``html`` and is written into the Divs'
elements in the page (their models' ``text`` is set only before the page has applied an
update and when the display pauses: a change of it lays the whole page out again).
"""

from __future__ import annotations

import math
import time

import numpy as np

PANELS = ("carriers", "spectrum", "coupling", "sensors", "trail")
#: The panels of ``openemt collect --view`` (no per-sample poses: no coupling, sensors, trail).
COLLECT_PANELS = ("collect", "carriers", "spectrum")
#: Every panel a page can show (``?panel=NAME``).
ALL_PANELS = ("collect", *PANELS)
_COLOURS = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2",
            "#7f7f7f", "#bcbd22", "#17becf")


def _fmt(v, spec="{:.3g}"):
    return "-" if v is None or (isinstance(v, float) and not math.isfinite(v)) else spec.format(v)


class Page:
    """The models of one tab and the function that refreshes them from a snapshot."""

    def __init__(self, doc, feed, *, period_ms: float, stats, panels=PANELS):
        from bokeh.layouts import column, row
        from bokeh.models import (
            ColumnDataSource,
            CustomJS,
            Div,
            Range1d,
            Toggle,
        )
        from bokeh.plotting import figure

        self.feed, self.stats, self.doc = feed, stats, doc
        self._plots: list = []
        self.seen = None
        self.n_updates = 0
        # a fixed size: new text then changes no layout (a Div that may resize makes the
        # browser lay the page out again on every update)
        self.header = Div(text="openemt live view: waiting for the session", name="title",
                          width=640, height=24)
        self.pause = Toggle(label="Pause display", active=False, button_type="default",
                            name="pause", width=140)
        self.src_header = ColumnDataSource({"n_updates": [0], "version": [-1],
                                            "paused": [False]}, name="header")
        parts = [row(self.header, self.pause)]
        self.src = {}

        def table(name, cols):
            """A table shown as HTML in a Div (named ``<name>_table``) and its values at full
            precision in a data source (named ``name``)."""
            src = ColumnDataSource({c[0]: [] for c in cols}, name=name)
            self.src[name] = src
            self.tables[name] = (Div(text="", name=f"{name}_table"), cols)
            doc.add_root(src)
            return self.tables[name][0]

        self.tables = {}
        if "collect" in panels:
            parts.append(self._collect_panel(table, figure, row, column, Div, ColumnDataSource,
                                             Range1d))
        if "carriers" in panels:
            t = table("carriers", [("frequency_hz", "carrier (Hz)", "{:g}"),
                                   ("reference_v", "drive level (V)", "{:.4g}"),
                                   ("sensor_mv", "sensor level (mV rms)", "{:.4g}"),
                                   ("coupling", "coupling level", "{:.4g}"),
                                   ("snr_db", "SNR (dB)", "{:.1f}"),
                                   ("quadrature", "quadrature ratio", "{:.2e}")])
            parts.append(column(Div(text="<b>Carriers</b>"), t, name="panel-carriers"))
        if "spectrum" in panels:
            self.src["spectrum"] = ColumnDataSource({"xs": [], "ys": [], "colour": [],
                                                     "channel": []}, name="spectrum")
            # fixed ranges, moved from here only when the data leave them: an auto-ranged
            # plot re-lays out its axes on every update (most of the browser's work)
            self._spec_x, self._spec_y = Range1d(0, 1), Range1d(-160, 10)
            f = figure(width=900, height=300, x_axis_label="frequency (Hz)",
                       x_range=self._spec_x, y_range=self._spec_y,
                       y_axis_label="amplitude (dB re 1 V)", tools="box_zoom,reset",
                       title="Spectrum per channel", name="spectrum_plot")
            f.multi_line("xs", "ys", source=self.src["spectrum"], line_color="colour",
                         line_width=1)
            self._plots.append(f)
            self._spec_key = Div(text="", name="spectrum_key")      # the colours, once
            parts.append(column(f, self._spec_key, name="panel-spectrum"))
        if "coupling" in panels:
            self.src["coupling"] = ColumnDataSource(
                {"carrier": [], "coil": [], "value": [], "quadrature": [], "norm": [],
                 "text": []}, name="coupling")
            # an HTML table with coloured cells: changing its text lays out only the table,
            # where a plot is redrawn whole (axes and all) on every update
            self._coupling_div = Div(text="", name="coupling_table")
            doc.add_root(self.src["coupling"])
            parts.append(column(Div(text="<b>Coupling matrix</b> (real part; colour: value / "
                                    "largest |value|, blue negative, red positive)"),
                                self._coupling_div, name="panel-coupling"))
        if "sensors" in panels:
            t = table("sensors", [("name", "sensor", "{}"), ("status", "status", "{}"),
                                  ("distortion", "quadrature ratio", "{:.2e}"),
                                  ("distorted", "distorted", "{}"),
                                  ("residual", "residual", "{:.2e}"),
                                  ("x_mm", "x (mm)", "{:.3f}"), ("y_mm", "y (mm)", "{:.3f}"),
                                  ("z_mm", "z (mm)", "{:.3f}"), ("rx_deg", "rx (deg)", "{:.3f}"),
                                  ("ry_deg", "ry (deg)", "{:.3f}"),
                                  ("rz_deg", "rz (deg)", "{:.3f}"),
                                  ("n_samples", "samples", "{}"), ("time_s", "time (s)", "{:.4f}")])
            parts.append(column(Div(text="<b>Sensors</b>"), t, name="panel-sensors"))
        if "trail" in panels:
            # per sensor a line (one path to draw, where a marker per point costs the browser
            # a path each) and a dot at its latest pose, drawn by the same glyph (a segment a
            # thousandth of the view long, 10 px wide with round caps): each glyph whose data
            # change costs BokehJS about 1.7 ms per update, whatever it draws
            self.src["trail"] = ColumnDataSource({"x": [], "y": [], "z": [], "colour": [],
                                                  "width": [], "alpha": [], "sensor": [],
                                                  "kind": []}, name="trail")
            figs = []
            self._trail_ranges = {a: Range1d(-10, 10) for a in "xyz"}
            for a, b in (("x", "y"), ("x", "z"), ("y", "z")):
                f = figure(width=300, height=300, x_range=self._trail_ranges[a],
                           y_range=self._trail_ranges[b],
                           title=f"trail {a}-{b} (mm)", x_axis_label=f"{a} (mm)",
                           y_axis_label=f"{b} (mm)", tools="", toolbar_location=None)
                f.multi_line(a, b, source=self.src["trail"], line_color="colour",
                             line_width="width", line_alpha="alpha", line_cap="round",
                             level="overlay")
                figs.append(f)
                self._plots.append(f)
            self._trail_key = Div(text="", name="trail_key")
            parts.append(column(Div(text="<b>Trail in the volume</b> (converged poses of the "
                                    "last seconds; a dot: the latest pose)"), row(*figs),
                                self._trail_key, name="panel-trail"))
        doc.add_root(column(*parts))
        doc.add_root(self.src_header)
        # the changing HTML (the header line and the tables) goes to the page in a data source
        # and is written into each Div's element there: setting a Div's ``text`` makes BokehJS
        # lay the whole page out again and redraw every plot (about half of the browser's work
        # per update when it did); the Divs' ``text`` is set only when the display pauses
        self.src_html = ColumnDataSource({"name": [], "html": []}, name="html")
        doc.add_root(self.src_html)
        self._html: dict = {}
        self.src_html.js_on_change("data", CustomJS(args={"src": self.src_html}, code="""
            const d = src.data;
            const get = (k) => (d instanceof Map ? d.get(k) : d[k]);
            const names = get("name"), html = get("html");
            const doc = src.document;
            for (let i = 0; i < names.length; i++) {
              const m = doc.get_model_by_name(names[i]);
              if (m == null) continue;
              const index = window.Bokeh && Bokeh.index;
              const v = index && index.find_one ? index.find_one(m) : null;
              if (v != null && v.markup_el != null) {
                if (v.markup_el.innerHTML !== html[i]) v.markup_el.innerHTML = html[i];
              } else if (m.text !== html[i]) {
                m.text = html[i];          // no view to write into: the slow way
              }
            }
            """))
        # BokehJS measures every axis's tick labels and the title of a plot each time it
        # repaints it, to decide whether the plot's layout must change (about 1 ms per plot
        # per update here); the ranges are fixed and move rarely, so each plot's check is
        # wrapped (once its view exists, the first time an update arrives) to run only when
        # its ranges or its size have changed since the last check, or a layout is asked for.
        # A BokehJS without this method keeps its own behaviour.
        # flow control: the page acknowledges every update it has applied, and the server
        # keeps at most two in flight, so a slow browser shows the latest state at its own
        # pace instead of falling further and further behind
        self.src_ack = ColumnDataSource({"n": [0]}, name="ack")
        doc.add_root(self.src_ack)
        self.src_ack.on_change("data", lambda attr, old, new: stats.applied(
            id(self), new["n"][0]))
        self.src_header.js_on_change("data", CustomJS(
            args={"ack": self.src_ack, "header": self.src_header, "plots": self._plots},
            code="""
            const d = header.data;
            const n = (d instanceof Map ? d.get("n_updates") : d.n_updates)[0];
            ack.data = (ack.data instanceof Map) ? new Map([["n", [n]]]) : {n: [n]};
            const index = window.Bokeh && Bokeh.index;
            for (const p of plots) {
              const v = index && index.find_one ? index.find_one(p) : null;
              if (v == null || v._openemt_layout ||
                  typeof v._invalidate_layout_if_needed !== "function") continue;
              const check = v._invalidate_layout_if_needed.bind(v);
              let last = null;
              v._openemt_layout = true;
              v._invalidate_layout_if_needed = () => {
                const b = v.bbox || {};
                const key = [p.x_range.start, p.x_range.end, p.y_range.start, p.y_range.end,
                             b.width, b.height].join(",");
                if (v._needs_layout || key !== last) {
                  last = key;
                  check();
                }
              };
            }
            """))
        self.skipped, self.sent = 0, 0.0
        self._sent_html: dict = {}
        doc.title = "openemt live view"
        self.cb = doc.add_periodic_callback(self.update, period_ms)

    def update(self) -> None:
        from bokeh.core.property.validation import without_property_validation

        without_property_validation(self._update)()       # the values are ours: no checks

    def _update(self) -> None:
        if self.pause.active:                       # pauses the display only
            if not self.src_header.data["paused"][0]:
                self.src_header.data = dict(self.src_header.data, paused=[True])
                for div, html in self._html.values():       # the models say what is shown
                    div.text = html
            return
        now = time.monotonic()
        if self.n_updates - self.src_ack.data["n"][0] >= 2 and now - self.sent < 0.5:
            self.skipped += 1                      # the page has not caught up yet
            return
        snap = self.feed.snapshot()
        if snap["version"] == self.seen and not self.src_header.data["paused"][0]:
            return                                 # nothing new: nothing sent
        self.sent = now
        self.n_updates += 1
        self.stats.tick()
        self.src_header.data = {"n_updates": [self.n_updates], "version": [snap["version"]],
                                "paused": [False]}
        self.seen = snap["version"]
        sensors = snap["sensors"]
        n = max((s["n_samples"] for s in sensors), default=0)
        t = max((s.get("time", 0.0) for s in sensors), default=0.0)
        src = snap.get("source") or "session"
        if "collect" in snap:
            c = snap["collect"]
            what = (f"sensor {c['sensor']}: {c['n_used']}/{c['n_target']} dwells, "
                    f"{c['tracker_seconds']:.1f} s of signal")
        else:
            what = f"{n} samples, t = {t:.2f} s, {len(sensors)} sensor(s)"
        self._set_html(self.header, f"<b>openemt live view</b> ({src}): {what}")
        if "collect" in self.src and "collect" in snap:
            self._collect(snap["collect"])
        if "carriers" in self.src:
            self._carriers(snap)
        if "spectrum" in self.src and "spectrum" in snap:
            self._spectrum(snap)
        if "coupling" in self.src:
            self._coupling(snap)
        if "sensors" in self.src:
            self._sensors(sensors)
        if "trail" in self.src:
            self._trail(sensors)
        changed = {k: h for k, (div, h) in self._html.items() if self._sent_html.get(k) != h}
        if changed and not self.src_ack.data["n"][0]:
            # the page has applied no update yet: what is sent now may arrive within the
            # document it loads, where no change callback runs, so the Divs get it themselves
            for k, h in changed.items():
                self._html[k][0].text = h
        if changed:
            self.src_html.data = {"name": list(changed), "html": list(changed.values())}
            self._sent_html.update(changed)

    def _set_html(self, div, html: str) -> None:
        """Show ``html`` in ``div`` (sent with the update, see ``src_html``)."""
        self._html[div.name] = (div, html)

    def _show(self, name, data) -> None:
        """Put ``data`` in the source ``name`` and its HTML table in the Div beside it."""
        self.src[name].data = data
        div, cols = self.tables[name]
        n = len(next(iter(data.values()), []))
        head = "".join(f"<th>{c[1]}</th>" for c in cols)
        body = "".join("<tr>" + "".join(f"<td>{_fmt(data[c[0]][r], c[2])}</td>" for c in cols)
                       + "</tr>" for r in range(n))
        self._set_html(div, (
            f'<table class="openemt" style="border-collapse: collapse; '
            f'font: 12px monospace"><tr style="text-align: left">{head}</tr>{body}'
            f"</table>").replace("<td>", '<td style="padding: 2px 10px">').replace(
                "<th>", '<th style="padding: 2px 10px; border-bottom: 1px solid #999">'))

    def _collect_panel(self, table, figure, row, column, Div, ColumnDataSource, Range1d):
        """The collect panel: the dwell count and coverage (a table), where the dwells are in
        the working volume (x-y and x-z, the volume's box drawn) and how the sensor pointed
        (its z axis: azimuth and elevation)."""
        from bokeh.models import CDSView, GroupFilter

        t = table("collect", [("n_dwells", "dwells", "{}"), ("n_target", "target", "{}"),
                              ("n_min", "calibrate needs", "{}"),
                              ("volume_coverage_pct", "volume (%)", "{:.1f}"),
                              ("outside", "outside", "{}"),
                              ("orientation_spread_deg", "orient. spread (deg)", "{:.1f}"),
                              ("rotation_diversity", "rot. diversity", "{}"),
                              ("rotation_second_axis_deg", "2nd axis (deg)", "{:.1f}"),
                              ("time_offset_ms", "time offset (ms)", "{:.1f}"),
                              ("tracker_seconds", "signal (s)", "{:.1f}"),
                              ("state", "state", "{}")])
        self.src["dwells"] = ColumnDataSource({"x": [], "y": [], "z": [], "azimuth": [],
                                               "elevation": []}, name="dwells")
        self.src["volume"] = ColumnDataSource({"left": [], "right": [], "bottom": [], "top": [],
                                               "view": []}, name="volume")
        self._collect_ranges = {a: Range1d(-10, 10) for a in "xyz"}
        figs = []
        for a, b in (("x", "y"), ("x", "z")):
            f = figure(width=300, height=300, x_range=self._collect_ranges[a],
                       y_range=self._collect_ranges[b], title=f"dwells {a}-{b} (mm)",
                       x_axis_label=f"{a} (mm)", y_axis_label=f"{b} (mm)", tools="",
                       toolbar_location=None)
            view = self.src["volume"]
            f.quad("left", "right", "bottom", "top", source=view, fill_alpha=0.05,
                   line_color="#999", line_dash="dashed",
                   view=CDSView(filter=GroupFilter(column_name="view", group=a + b)))
            f.scatter(a, b, source=self.src["dwells"], size=6, color=_COLOURS[0])
            figs.append(f)
        f = figure(width=360, height=300, x_range=Range1d(-180, 180), y_range=Range1d(-90, 90),
                   title="sensor z axis of each dwell (deg)", x_axis_label="azimuth (deg)",
                   y_axis_label="elevation (deg)", tools="", toolbar_location=None)
        f.scatter("azimuth", "elevation", source=self.src["dwells"], size=6,
                  color=_COLOURS[1])
        figs.append(f)
        return column(Div(text="<b>Collection</b>: dwells kept against the target (--n-poses) "
                          "and the minimum calibrate --mode reference needs; coverage of the "
                          "working volume (dashed) and of orientations"), t, row(*figs),
                      name="panel-collect")

    def _collect(self, c):
        cov = c["coverage"]
        state = ("ended: " + str(c["ended_by"]) if c["ended_by"] else
                 "collecting" if c["locked"] else "waiting for the time offset")
        self._show("collect", {
            "n_dwells": [c["n_used"]], "n_target": [c["n_target"]], "n_min": [c["n_min"]],
            "volume_coverage_pct": [cov["volume_coverage_pct"]], "outside": [cov["outside"]],
            "orientation_spread_deg": [_num(cov["orientation_spread_deg"])],
            "rotation_diversity": ["ok" if cov["rotation_diversity_ok"] else "NOT yet"],
            "rotation_second_axis_deg": [_num(cov["rotation_second_axis_deg"])],
            "time_offset_ms": [_num(c["time_offset_ms"])],
            "tracker_seconds": [c["tracker_seconds"]], "state": [state]})
        p = c["positions_mm"]
        self.src["dwells"].data = {"x": p[:, 0].copy(), "y": p[:, 1].copy(), "z": p[:, 2].copy(),
                                   "azimuth": c["azimuth_deg"], "elevation": c["elevation_deg"]}
        (lx, ly, lz), (hx, hy, hz) = c["box_mm"]
        box = {"left": [lx, lx], "right": [hx, hx], "bottom": [ly, lz], "top": [hy, hz],
               "view": ["xy", "xz"]}
        if self.src["volume"].data != box:
            self.src["volume"].data = box
            # one scale on the three axes (equal aspect), the box and a margin in view
            half = 0.6 * float(max(hx - lx, hy - ly, hz - lz))
            for a, lo, hi in (("x", lx, hx), ("y", ly, hy), ("z", lz, hz)):
                m = 0.5 * (lo + hi)
                self._collect_ranges[a].update(start=m - half, end=m + half)

    def _carriers(self, snap):
        c = snap.get("carriers")
        if not c:
            return
        k = len(next(iter(v for v in c.values() if np.ndim(v))))
        f = snap.get("frequencies") or [float("nan")] * k     # a log names no carrier

        def col(key, scale=1.0):
            v = c.get(key)
            return [float("nan")] * k if v is None else [float(x) * scale for x in v]

        self._show("carriers", {
            "frequency_hz": [float(x) for x in f], "reference_v": col("reference_level"),
            "sensor_mv": col("sensor_level", 1e3), "coupling": col("coupling_level"),
            "snr_db": col("snr_db"), "quadrature": col("quadrature")})

    def _spectrum(self, snap):
        s = snap["spectrum"]
        names = _channel_names(self.feed)
        f = s["frequencies"].astype(np.float32)
        db = s["db"].astype(np.float32)
        k = db.shape[1]
        self.src["spectrum"].data = {
            "xs": [f] * k, "ys": [np.ascontiguousarray(db[:, j]) for j in range(k)],
            "colour": [_COLOURS[j % len(_COLOURS)] for j in range(k)],
            "channel": [names.get(j, f"ch{j}") for j in range(k)]}
        key = _key(self.src["spectrum"].data["channel"])
        if self._spec_key.text != key:
            self._spec_key.text = key
        top = float(f[-1]) if len(f) else 1.0
        if self._spec_x.end != top:
            self._spec_x.update(start=0.0, end=top)
        finite = db[np.isfinite(db)]
        if finite.size:
            lo, hi = float(np.percentile(finite, 1)), float(finite.max())
            y = self._spec_y
            if lo < y.start or hi > y.end or lo > y.start + 30 or hi < y.end - 30:
                y.update(start=10 * math.floor(lo / 10) - 10, end=10 * math.ceil(hi / 10) + 10)

    def _coupling(self, snap):
        blocks = [(s["name"], s["couplings"]) for s in snap["sensors"]
                  if s.get("couplings") is not None]
        if not blocks:
            return
        f = snap.get("frequencies")
        carrier, coil, value, quad, text = [], [], [], [], []
        for name, C in blocks:
            n_so, n_se = C.shape
            labels = ([f"{x:g} Hz" for x in f] if f is not None and len(f) == n_so
                      else [f"source {i}" for i in range(n_so)])
            for i in range(n_so):
                for j in range(n_se):
                    carrier.append(labels[i])
                    coil.append(f"{name}.{j}")
                    value.append(float(C[i, j].real))
                    quad.append(float(C[i, j].imag))
                    text.append(f"{C[i, j].real:.3g}")
        m = max((abs(v) for v in value), default=0.0) or 1.0
        norm = [v / m for v in value]
        self.src["coupling"].data = {"carrier": carrier, "coil": coil, "value": value,
                                     "quadrature": quad, "norm": norm, "text": text}
        palette = _diverging()
        coils = list(dict.fromkeys(coil))
        cell = {(a, b): (t, u) for a, b, t, u in zip(carrier, coil, text, norm)}
        td = '<td style="padding: 3px 8px; text-align: center; background: {}">{}</td>'
        body = "".join(
            f'<tr><th style="padding: 3px 8px; text-align: right">{a}</th>' + "".join(
                td.format(palette[min(63, int(round((cell[a, b][1] + 1) * 31.5)))],
                          cell[a, b][0]) if (a, b) in cell else "<td></td>" for b in coils)
            + "</tr>" for a in dict.fromkeys(carrier))
        head = "".join(f'<th style="padding: 3px 8px">{b}</th>' for b in coils)
        self._set_html(self._coupling_div, (
            f'<table style="border-collapse: collapse; font: 12px monospace"><tr><th>carrier '
            f'\\ sensor coil</th>{head}</tr>{body}</table>'))

    def _sensors(self, sensors):
        rows = [s for s in sensors if s["n_samples"]]
        v = [s["pose_vector"] for s in rows]
        self._show("sensors", {
            "name": [s["name"] for s in rows], "status": [s["status"] for s in rows],
            "distortion": [s["distortion"] for s in rows],
            "distorted": ["yes" if s["distorted"] else "no" for s in rows],
            "residual": [s["residual"] for s in rows],
            "x_mm": [1e3 * p[0] for p in v], "y_mm": [1e3 * p[1] for p in v],
            "z_mm": [1e3 * p[2] for p in v],
            "rx_deg": [math.degrees(p[3]) for p in v], "ry_deg": [math.degrees(p[4]) for p in v],
            "rz_deg": [math.degrees(p[5]) for p in v],
            "n_samples": [s["n_samples"] for s in rows],
            "time_s": [s["time"] for s in rows]})

    def _trail(self, sensors):
        lines = {"x": [], "y": [], "z": [], "colour": [], "width": [], "alpha": [],
                 "sensor": [], "kind": []}
        shown = [(k, s) for k, s in enumerate(sensors) if s["n_samples"]]
        trails = [np.concatenate([1e3 * s["trail"], 1e3 * s["pose_vector"][None, :3]])
                  for _, s in shown]
        tr = np.concatenate(trails) if trails else np.empty((0, 3))
        pts = tr[np.isfinite(tr).all(axis=1)]
        r = self._trail_ranges
        if len(pts):
            # one scale on all three axes (equal aspect), moved when a point leaves the
            # view or the points fill less than a third of it
            lo, hi = pts.min(axis=0), pts.max(axis=0)
            span = r["x"].end - r["x"].start
            need = max(float((hi - lo).max()), 10.0)
            out = any(lo[i] < r[a].start or hi[i] > r[a].end for i, a in enumerate("xyz"))
            if out or need < span / 3:
                half = 0.65 * need
                for i, a in enumerate("xyz"):
                    c = 0.5 * float(lo[i] + hi[i])
                    r[a].update(start=c - half, end=c + half)
        d = 1e-3 * (r["x"].end - r["x"].start)      # the dot's segment (mm)
        for (k, s), t in zip(shown, trails):
            colour = _COLOURS[k % len(_COLOURS)]
            p = t[-1]
            dot = np.stack([p - d, p + d])
            for line, width, alpha, kind in ((t, 1.0, 0.7, "trail"), (dot, 10.0, 1.0, "latest")):
                line = line.astype(np.float32)
                for i, key in enumerate("xyz"):
                    lines[key].append(np.ascontiguousarray(line[:, i]))
                lines["colour"].append(colour)
                lines["width"].append(width)
                lines["alpha"].append(alpha)
                lines["sensor"].append(s["name"])
                lines["kind"].append(kind)
        self.src["trail"].data = lines
        key = _key([s["name"] for _, s in shown],
                   [_COLOURS[k % len(_COLOURS)] for k, _ in shown])
        if self._trail_key.text != key:
            self._trail_key.text = key


def _num(v) -> float:
    return float("nan") if v is None else float(v)


def _key(names, colours=None) -> str:
    """A colour key in HTML: each name in its colour."""
    colours = colours or [_COLOURS[j % len(_COLOURS)] for j in range(len(names))]
    return "&nbsp; ".join(f'<span style="color: {c}">&#9632; {n}</span>'
                          for n, c in zip(names, colours))


def _diverging():
    """A blue-white-red palette of 64 colours (negative blue, positive red)."""
    out = []
    for k in range(64):
        u = k / 63 * 2 - 1
        if u < 0:
            r, g, b = 1 + u, 1 + u, 1.0
        else:
            r, g, b = 1.0, 1 - u, 1 - u
        out.append(f"#{int(55 + 200 * r):02x}{int(55 + 200 * g):02x}{int(55 + 200 * b):02x}")
    return out


def _channel_names(feed) -> dict:
    lay = feed.layout
    if lay is None:
        return {}
    out = {}
    names = feed.names
    per = len(lay.sensor_channels) // max(1, len(names)) if names else 0
    for j, c in enumerate(lay.sensor_channels):
        if per and len(names) * per == len(lay.sensor_channels):
            out[c] = f"{names[j // per]}.{j % per} (ch {c})"
        else:
            out[c] = f"sensor coil {j} (ch {c})"
    for i, c in enumerate(lay.reference_channels):
        out[c] = f"reference {lay.frequencies[i]:g} Hz (ch {c})"
    return out
