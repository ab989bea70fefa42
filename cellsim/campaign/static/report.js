// The campaign report's script: inlined into report.html by cellsim.campaign.report.
//
// It is the report's only timeline renderer. On load it draws the runs the page shows in
// full (the first violating run of each violated condition: every element with a
// data-draw attribute), so a printed page or a PDF shows them; a click on a run in the
// runs table draws that run's timeline under its row with the same function. It also
// sorts and filters the runs table and opens the run named in the address (#run-7).
//
// Everything is built with DOM calls (textContent, setAttribute): no string of the data
// is ever parsed as markup, so nothing here escapes by hand.
//
// Timeline geometry, in SVG user units (the SVG has a viewBox and scales to the page
// width): time t in [0, duration] is at x = plotLeft + plotWidth * t / duration, clamped.
// Ticks every 5 s (labels thinned when crowded); one lane per variable, grouped under
// titles; violation labels on rows of their own above the axis, so none overlaps another.
(function () {
  "use strict";

  var G = {
    svgWidth: 1000,
    plotLeft: 170,       // the lane labels sit left of this
    plotWidth: 810,      // svgWidth - plotLeft - a right margin of 20
    lane: 20,            // an enumerated or boolean lane
    numericLane: 40,     // a step plot
    gap: 4,              // between lanes
    group: 18,           // a group's title
    axisHeight: 22,      // tick labels above the lanes
    markerRow: 13,       // one row of violation labels
    tick: 5,             // seconds between ticks
    minLabelSpacing: 36, // tick labels closer than this are thinned
    minPiece: 1.5,       // a piece of a few milliseconds stays visible, on screen and on paper
    charWidth: 6.4       // about the width of a character at 11px
  };
  G.labelRoom = Math.floor((G.plotLeft - 10) / G.charWidth);  // characters of a lane label
  var SVG_NS = "http://www.w3.org/2000/svg";  // a name, not an address: nothing is fetched

  var data = null;
  function load() {
    if (!data) data = JSON.parse(document.getElementById("report-data").textContent);
    return data;
  }

  // ------------------------------------------------------------------ building elements

  function fill(node, attrs, children) {
    Object.keys(attrs || {}).forEach(function (k) { node.setAttribute(k, attrs[k]); });
    (children || []).forEach(function (c) {
      if (c !== null && c !== undefined) node.appendChild(typeof c === "string" ? document.createTextNode(c) : c);
    });
    return node;
  }
  function svg(tag, attrs, children) { return fill(document.createElementNS(SVG_NS, tag), attrs, children); }
  function html(tag, attrs, children) { return fill(document.createElement(tag), attrs, children); }
  function titled(tip, children) { return svg("g", {}, [svg("title", {}, [tip])].concat(children)); }
  function n2(x) { return x.toFixed(2); }

  // ------------------------------------------------------------------ numbers, as cellsim.numbers

  function instant(t) { return typeof t === "number" ? t.toFixed(2) + " s" : "\u2014"; }  // a moment of a run, 10 ms
  function sig3(x) {  // three significant figures; the exponent is the rounded value's, two digits at least
    if (typeof x !== "number" || !isFinite(x)) return String(x);
    if (x === 0) return "0";
    var e = x.toExponential(2).split("e"), exponent = parseInt(e[1], 10);
    if (exponent >= -3 && exponent < 5) return x.toFixed(Math.max(0, 2 - exponent));
    var digits = String(Math.abs(exponent));
    return e[0] + "e" + (exponent < 0 ? "-" : "+") + (digits.length < 2 ? "0" + digits : digits);
  }
  function textColour(colour) {  // black or white, whichever reads better on #rrggbb
    var r = parseInt(colour.slice(1, 3), 16), g = parseInt(colour.slice(3, 5), 16), b = parseInt(colour.slice(5, 7), 16);
    return 0.299 * r + 0.587 * g + 0.114 * b > 140 ? "#000" : "#fff";
  }

  // ------------------------------------------------------------------ traces

  // A compact trace [steps (ms from the previous sample), values] cut into constant pieces
  // [t0, t1, value] over [0, duration): a sample holds until the next one, the last until
  // the end; pieces are clipped to the run. Repeated values were dropped when the page was written.
  function pieces(steps, values, duration) {
    var out = [], times = [], t = 0;
    steps.forEach(function (step) { t += step; times.push(t); });
    for (var i = 0; i < times.length; i++) {
      var t0 = Math.max(times[i] / 1000, 0), t1 = Math.min(i + 1 < times.length ? times[i + 1] / 1000 : duration, duration);
      if (t1 > t0) out.push([t0, t1, values[i]]);
    }
    return out;
  }

  // Intervals where a macro or atom held, as a compact boolean trace from 0.
  function heldTrace(intervals) {
    var steps = [0], values = ["false"], last = 0;
    (Array.isArray(intervals) ? intervals : []).forEach(function (iv) {
      if (!Array.isArray(iv) || typeof iv[0] !== "number" || typeof iv[1] !== "number") return;
      var from = Math.round(iv[0] * 1000), to = Math.round(iv[1] * 1000);
      steps.push(from - last, to - from);
      values.push("true", "false");
      last = to;
    });
    return [steps, values];
  }

  // Violation labels placed on rows so that none overlaps another: [x, name, t, row, atEnd].
  function markerRows(marks) {
    var ends = [];
    return marks.slice().sort(function (a, b) { return a[0] - b[0] || (a[1] < b[1] ? -1 : a[1] > b[1] ? 1 : 0); })
      .map(function (m) {
        var width = m[1].length * G.charWidth + 6, atEnd = m[0] + width > G.svgWidth;
        var from = atEnd ? m[0] - width : m[0], to = atEnd ? m[0] : m[0] + width, row = 0;
        while (row < ends.length && !(from > ends[row])) row++;
        ends[row] = to;
        return [m[0], m[1], m[2], row, atEnd];
      });
  }

  // ------------------------------------------------------------------ the timeline

  // One run's timeline as an SVG element: the lanes of its trace, grouped; for each
  // explained violation a group "Why <condition>" of its macros and atoms (dark where they
  // held) and the window it required shaded; a red line at each violation; ticks every 5 s.
  function timeline(run, index) {
    var d = load(), dur = d.duration;
    function X(t) { return G.plotLeft + G.plotWidth * Math.min(Math.max(t, 0), dur) / dur; }
    var marks = markerRows(run.violations.filter(function (v) { return typeof v[1] === "number" && isFinite(v[1]); })
      .map(function (v) { return [X(v[1]), v[0], v[1]]; }));
    var markerRowsUsed = marks.reduce(function (n, m) { return Math.max(n, m[3] + 1); }, 0);
    var labelTop = 2, axisTop = labelTop + markerRowsUsed * G.markerRow + G.axisHeight, y = axisTop;
    var under = [], lanes = [], over = [];

    var groups = d.groups.map(function (group) {
      return [group[0], group[1].filter(function (v) { return run.trace[v]; })
        .map(function (v) { return {name: v, trace: run.trace[v], why: false}; })];
    });
    Object.keys(run.evidence).forEach(function (condition) {
      var rows = run.evidence[condition].rows || {};
      groups.push(["Why " + condition, Object.keys(rows).map(function (r) { return {name: r, trace: heldTrace(rows[r]), why: true}; })]);
    });

    groups.forEach(function (group) {
      if (!group[1].length) return;
      lanes.push(svg("text", {"class": "group", x: 4, y: n2(y + 12)}, [group[0]]));
      y += G.group;
      group[1].forEach(function (lane) {
        var v = lane.name, numeric = !lane.why && d.kinds[v] === "numeric", h = numeric ? G.numericLane : G.lane;
        var unit = numeric ? d.units[v] || "" : "", label = unit ? v + " (" + unit + ")" : v;
        var fitted = label.length <= G.labelRoom ? label : label.slice(0, G.labelRoom - 1) + "\u2026";
        lanes.push(svg("text", {"class": "lane-label", x: n2(G.plotLeft - 6), y: n2(y + h / 2 + 4)}, [svg("title", {}, [label]), fitted]));
        lanes.push(svg("rect", {"class": "lane", x: n2(G.plotLeft), y: n2(y), width: n2(G.plotWidth), height: n2(h)}));
        var ps = pieces(lane.trace[0], lane.trace[1], dur);
        if (numeric) stepPlot(v, ps, lane.trace[2], y, unit, X);
        else pieceRects(v, ps, lane.why, y, X);
        y += h + G.gap;
      });
    });

    function stepPlot(v, ps, extremes, top, unit, X) {  // one polyline per defined stretch, an axis in the unit
      if (!extremes) return;
      var lo = extremes[0], hi = extremes[1], suffix = unit ? " " + unit : "", innerTop = top + 4, innerH = G.numericLane - 8;
      function Y(x) { return hi === lo ? innerTop + innerH / 2 : innerTop + innerH * (hi - x) / (hi - lo); }
      lanes.push(svg("line", {"class": "y-axis", x1: n2(G.plotLeft), x2: n2(G.plotLeft), y1: n2(innerTop), y2: n2(innerTop + innerH)}));
      (hi === lo ? [hi] : [hi, lo]).forEach(function (value) {
        lanes.push(svg("line", {"class": "y-tick", x1: n2(G.plotLeft - 3), x2: n2(G.plotLeft + G.plotWidth), y1: n2(Y(value)), y2: n2(Y(value))}));
      });
      var tip = v + ": min " + sig3(lo) + suffix + ", max " + sig3(hi) + suffix, points = [];
      function flush() {
        if (points.length) lanes.push(svg("polyline", {"class": "step", "data-var": v, points: points.join(" ")}, [svg("title", {}, [tip])]));
        points = [];
      }
      ps.forEach(function (p) {
        if (typeof p[2] !== "number") { flush(); return; }  // an undefined stretch breaks the line
        points.push(n2(X(p[0])) + "," + n2(Y(p[2])), n2(X(p[1])) + "," + n2(Y(p[2])));
      });
      flush();
      lanes.push(svg("text", {"class": "y-label", x: n2(G.plotLeft + 3), y: n2(Y(hi) + 9)}, [sig3(hi) + suffix]));
      if (hi !== lo) lanes.push(svg("text", {"class": "y-label", x: n2(G.plotLeft + 3), y: n2(Y(lo) - 2)}, [sig3(lo) + suffix]));
    }

    function pieceRects(v, ps, why, top, X) {  // a rect per defined piece, at least minPiece wide
      function narrow(p) { return X(p[1]) - X(p[0]) < G.minPiece; }
      // widened pieces last, over their neighbours: otherwise the next piece covers all but their true width
      ps.filter(function (p) { return !narrow(p); }).concat(ps.filter(narrow)).forEach(function (p) {
        if (p[2] === null) return;
        var text = String(p[2]), colour = why ? d.boolColours[text] : ((d.colours[v] || {})[text] || "#9e9e9e");
        var x0 = X(p[0]), x1 = X(p[1]), parts = [
          svg("rect", {"class": "piece", "data-var": v, x: n2(x0), y: n2(top), width: n2(Math.max(x1 - x0, G.minPiece)), height: n2(G.lane), fill: colour})
        ];
        if (x1 - x0 >= text.length * G.charWidth + 6) {
          parts.push(svg("text", {"class": "piece-label", x: n2((x0 + x1) / 2), y: n2(top + G.lane / 2 + 4), fill: textColour(colour)}, [text]));
        }
        lanes.push(titled(v + " = " + text + " from " + instant(p[0]) + " to " + instant(p[1]), parts));
      });
    }

    var bottom = y - G.gap;
    var perTick = G.plotWidth * G.tick / dur, every = Math.max(1, Math.ceil(G.minLabelSpacing / perTick));
    for (var k = 0; k * G.tick <= dur + 1e-9; k++) {  // labels thinned when they would crowd
      var tx = n2(X(k * G.tick));
      under.push(svg("line", {"class": "tick", x1: tx, x2: tx, y1: n2(axisTop - 4), y2: n2(bottom)}));
      if (k % every === 0) under.push(svg("text", {"class": "tick-label", x: tx, y: n2(axisTop - 7)}, [k * G.tick + " s"]));
    }
    Object.keys(run.evidence).forEach(function (condition) {
      var w = run.evidence[condition].window, top = axisTop + G.group;
      if (!w || w.length !== 2 || typeof w[0] !== "number" || typeof w[1] !== "number") return;
      under.push(titled(condition + ": required between " + instant(w[0]) + " and " + instant(w[1]), [
        svg("rect", {"class": "window", "data-condition": condition, x: n2(X(w[0])), y: n2(top),
                     width: n2(Math.max(X(w[1]) - X(w[0]), 2 * G.minPiece)), height: n2(bottom - top)})]));
    });
    marks.forEach(function (m) {
      var labelY = labelTop + (m[3] + 1) * G.markerRow - 3;
      over.push(titled(m[1] + " violated at " + instant(m[2]), [
        svg("line", {"class": "violation", "data-condition": m[1], x1: n2(m[0]), x2: n2(m[0]), y1: n2(labelY - 9), y2: n2(bottom)}),
        svg("text", {"class": "violation-label", x: n2(m[4] ? m[0] - 3 : m[0] + 3), y: n2(labelY), "text-anchor": m[4] ? "end" : "start"}, [m[1]])
      ]));
    });
    return svg("svg", {"class": "timeline", viewBox: "0 0 " + G.svgWidth + " " + n2(y + 4), width: "100%", role: "img",
                       "aria-label": "timeline of run " + index}, under.concat(lanes, over));
  }

  // ------------------------------------------------------------------ the runs drawn on load

  Array.prototype.forEach.call(document.querySelectorAll("[data-draw]"), function (slot) {
    var index = slot.getAttribute("data-draw"), run = load().runs[index];
    if (run && run.trace) slot.replaceChildren(timeline(run, index));
  });

  // ------------------------------------------------------------------ the runs table

  var table = document.getElementById("runs-table");
  if (!table) return;
  var body = table.tBodies[0];
  var rows = Array.prototype.slice.call(body.rows);
  var count = document.getElementById("run-count");
  function closeAll() {
    Array.prototype.slice.call(body.querySelectorAll("tr.details")).forEach(function (d) { d.remove(); });
  }
  function cellValue(row, col, kind) {
    var cell = row.cells[col];
    var v = cell.getAttribute("data-value");
    if (v === null) v = cell.textContent;
    if (kind === "num") { var n = parseFloat(v); return isNaN(n) ? -Infinity : n; }
    return v.toLowerCase();
  }
  Array.prototype.forEach.call(table.tHead.rows[0].cells, function (th, col) {
    var kind = th.getAttribute("data-sort");
    if (!kind) return;
    th.addEventListener("click", function () {
      var asc = !th.classList.contains("sorted-asc");
      Array.prototype.forEach.call(table.tHead.rows[0].cells, function (h) { h.classList.remove("sorted-asc", "sorted-desc"); });
      th.classList.add(asc ? "sorted-asc" : "sorted-desc");
      closeAll();
      var keyed = rows.map(function (r) { return [cellValue(r, col, kind), r]; });
      keyed.sort(function (a, b) { return (a[0] < b[0] ? -1 : a[0] > b[0] ? 1 : 0) * (asc ? 1 : -1); });
      rows = keyed.map(function (k) { return k[1]; });
      var all = document.createDocumentFragment();
      rows.forEach(function (r) { all.appendChild(r); });
      body.appendChild(all);
    });
  });
  var text = document.getElementById("run-filter"), verdict = document.getElementById("verdict-filter");
  function filter() {
    var q = text.value.trim().toLowerCase(), want = verdict.value, shown = 0;
    closeAll();
    rows.forEach(function (r) {
      var ok = (!want || r.getAttribute("data-verdict") === want) && (!q || r.textContent.toLowerCase().indexOf(q) >= 0);
      r.hidden = !ok;
      if (ok) shown++;
    });
    count.textContent = shown + " of " + rows.length + " runs";
  }
  text.addEventListener("input", filter);
  verdict.addEventListener("change", filter);

  // A run opened under its row: why each violation happened, its error, the command that
  // re-runs it, and its timeline (drawn by timeline(), as the runs drawn on load are).
  function open(row) {
    var next = row.nextElementSibling;
    if (next && next.classList.contains("details")) { next.remove(); return; }
    var index = row.getAttribute("data-run"), run = load().runs[index], parts = [];
    if (run.violations.length) {
      parts.push(html("ul", {}, run.violations.map(function (v) {
        return html("li", {}, [html("strong", {}, [v[0]]), " violated at " + instant(v[1]), v[2] ? ": " + v[2] : null]);
      })));
    }
    if (run.error) parts.push(html("pre", {"class": "error"}, [run.error]));
    if (run.rerun) parts.push(html("p", {}, ["Re-run: ", html("code", {}, [run.rerun])]));
    parts.push(run.trace ? timeline(run, index) : html("p", {"class": "muted"}, ["No trace available for this run."]));
    var details = html("tr", {"class": "details"}, [html("td", {colspan: String(row.cells.length)}, parts)]);
    row.parentNode.insertBefore(details, row.nextSibling);
  }
  body.addEventListener("click", function (ev) {
    var link = ev.target.closest("a.open");
    if (!link) return;
    ev.preventDefault();
    open(link.closest("tr"));
  });
  function openFromHash() {
    var row = location.hash && document.getElementById(location.hash.slice(1));
    if (row && row.parentNode === body && !(row.nextElementSibling && row.nextElementSibling.classList.contains("details"))) {
      row.hidden = false;
      open(row);
      row.scrollIntoView();
    }
  }
  window.addEventListener("hashchange", openFromHash);
  openFromHash();
})();
