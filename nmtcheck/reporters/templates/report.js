/* nmtcheck report: timelines (SVG, zoom and pan), sortable and filterable findings.
   No dependencies and no network: everything comes from the JSON in #report-data. */
(function () {
  "use strict";
  var data = JSON.parse(document.getElementById("report-data").textContent);
  var SVGNS = "http://www.w3.org/2000/svg";
  // Row layout: a marker lane above each state bar; the time axis on top.
  var LABEL_W = 110, PAD_R = 16, AXIS_H = 26, ROW_H = 32, MARK_H = 9, BAR_H = 18, BOTTOM = 4;
  var MIN_SPAN = 1e-4;  // 0.1 ms: below the resolution of any CAN log
  var DARK_STATES = { "OFFLINE": true, "STOPPED": true };
  var timelines = {};

  function el(name, attrs, parent, text) {
    var node = document.createElementNS(SVGNS, name);
    for (var key in attrs) {
      if (Object.prototype.hasOwnProperty.call(attrs, key)) { node.setAttribute(key, attrs[key]); }
    }
    if (text !== undefined) { node.textContent = text; }
    if (parent) { parent.appendChild(node); }
    return node;
  }

  function niceStep(span, count) {
    var raw = span / Math.max(count, 1);
    var power = Math.pow(10, Math.floor(Math.log10(raw)));
    var steps = [1, 2, 5, 10];
    for (var i = 0; i < steps.length; i++) {
      if (steps[i] * power >= raw) { return steps[i] * power; }
    }
    return 10 * power;
  }

  function decimalsFor(step) {
    return Math.max(0, Math.min(6, -Math.floor(Math.log10(step) + 1e-9)));
  }

  /* A time on a timeline: seconds, or in a log without timestamps (spec.frames) the frame
     it stands for, counted from 1 (its time is the frame index). */
  function when(spec, t) {
    return spec.frames ? "frame " + (Math.round(t) + 1) : t.toFixed(6) + " s";
  }

  function Timeline(figure, spec) {
    this.figure = figure;
    this.spec = spec;
    this.svg = figure.querySelector("svg.tl-svg");
    this.total = Math.max(spec.duration, 1e-3);
    this.v0 = 0;
    this.v1 = this.total;
    this.focus = null;
    this.bind();
    this.render();
  }

  Timeline.prototype.plotWidth = function () {
    var width = this.svg.getBoundingClientRect().width || 900;
    return Math.max(width, 360) - LABEL_W - PAD_R;
  };

  Timeline.prototype.x = function (t) {
    return LABEL_W + (t - this.v0) / (this.v1 - this.v0) * this.plotW;
  };

  Timeline.prototype.timeAt = function (clientX) {
    var left = this.svg.getBoundingClientRect().left;
    return this.v0 + (clientX - left - LABEL_W) / this.plotW * (this.v1 - this.v0);
  };

  Timeline.prototype.setView = function (v0, v1) {
    var span = Math.min(Math.max(v1 - v0, MIN_SPAN), this.total);
    v0 = Math.min(Math.max(v0, 0), this.total - span);
    this.v0 = v0;
    this.v1 = v0 + span;
    this.scheduleRender();
  };

  Timeline.prototype.zoom = function (factor, center) {
    if (center === undefined) { center = (this.v0 + this.v1) / 2; }
    this.setView(center - (center - this.v0) * factor, center + (this.v1 - center) * factor);
  };

  Timeline.prototype.scheduleRender = function () {
    var self = this;
    if (this.pending) { return; }
    this.pending = true;
    window.requestAnimationFrame(function () { self.pending = false; self.render(); });
  };

  Timeline.prototype.render = function () {
    var spec = this.spec, svg = this.svg, self = this;
    this.plotW = this.plotWidth();
    var width = LABEL_W + this.plotW + PAD_R;
    // the SYNC row, then the LSS row, above the node rows
    var top = AXIS_H + (spec.sync ? ROW_H : 0) + (spec.lss ? ROW_H : 0);
    var height = top + spec.rows.length * ROW_H + BOTTOM;
    while (svg.firstChild) { svg.removeChild(svg.firstChild); }
    svg.setAttribute("viewBox", "0 0 " + width + " " + height);
    svg.setAttribute("height", height);
    svg.dataset.viewStart = this.v0;
    svg.dataset.viewEnd = this.v1;
    svg.dataset.plotX = LABEL_W;
    svg.dataset.plotWidth = this.plotW;
    var clipId = spec.id + "-clip";
    var defs = el("defs", {}, svg);
    el("rect", { x: LABEL_W, y: 0, width: this.plotW, height: height }, el("clipPath", { id: clipId }, defs));
    var hatch = el("pattern", { id: spec.id + "-hatch", width: 6, height: 6,
                                patternUnits: "userSpaceOnUse",
                                patternTransform: "rotate(45)" }, defs);
    el("rect", { width: 3, height: 6, fill: "rgba(0,0,0,0.28)" }, hatch);

    // Time axis: "nice" steps of 1, 2 or 5 x 10^k seconds, about one label per 90 px.
    var step = niceStep(this.v1 - this.v0, this.plotW / 90);
    if (spec.frames) { step = Math.max(step, 1); }  // whole frames
    var decimals = spec.frames ? 0 : decimalsFor(step);
    var axis = el("g", { "class": "axis" }, svg);
    for (var t = Math.ceil(this.v0 / step - 1e-9) * step; t <= this.v1 + 1e-12; t += step) {
      var tx = this.x(t);
      el("line", { "class": "grid", x1: tx, x2: tx, y1: AXIS_H, y2: height - BOTTOM }, axis);
      el("text", { "class": "tick-label", x: tx, y: AXIS_H - 9, "text-anchor": "middle" }, axis,
         spec.frames ? String(Math.round(t) + 1) : t.toFixed(decimals));
    }
    el("text", { "class": "tick-label axis-title", x: 8, y: AXIS_H - 9 }, axis,
       spec.frames ? "frame" : "time (s)");
    el("line", { "class": "axis-line", x1: LABEL_W, x2: LABEL_W + this.plotW, y1: AXIS_H - 0.5,
                 y2: AXIS_H - 0.5 }, axis);

    if (spec.sync) { this.renderSync(spec.sync, width, clipId); }
    if (spec.lss) { this.renderLss(spec.lss, width, clipId, AXIS_H + (spec.sync ? ROW_H : 0)); }

    spec.rows.forEach(function (row, i) {
      var y0 = top + i * ROW_H;
      var barY = y0 + MARK_H + 2;
      var g = el("g", { "class": "tl-row", "data-channel": spec.channel,
                        "data-node": row.node === null ? "network" : row.node,
                        "data-bar-y": barY, "data-bar-h": BAR_H }, svg);
      el("rect", { "class": "row-bg" + (i % 2 ? " alt" : ""), x: 0, y: y0, width: width,
                   height: ROW_H }, g);
      el("text", { "class": "row-label", x: 10, y: barY + 13 }, g, row.label);
      var bars = el("g", { "clip-path": "url(#" + clipId + ")" }, g);
      var lastEnd = -Infinity;
      row.iv.forEach(function (iv) {
        if (iv[1] < self.v0 || iv[0] > self.v1) { return; }
        var x0 = Math.max(self.x(iv[0]), LABEL_W - 1);
        var x1 = Math.min(self.x(iv[1]), LABEL_W + self.plotW + 1);
        if (x1 - x0 < 0.5 && x0 < lastEnd + 0.5) { return; }  // sub-pixel: one per pixel
        lastEnd = x1;
        var state = data.states[iv[2]];
        var rect = el("rect", { "class": "iv" + (iv[4] ? " rebooting" : ""), x: x0, y: barY,
                                width: Math.max(x1 - x0, 0.5), height: BAR_H,
                                fill: data.stateColors[state], "data-state": state,
                                "data-start": iv[0], "data-end": iv[1] }, bars);
        if (iv[4]) {  // boot-ups inside the state: the node kept rebooting (B003)
          rect.setAttribute("data-reboots", iv[4]);
          el("rect", { "class": "iv-rebooting", x: x0, y: barY, width: Math.max(x1 - x0, 0.5),
                       height: BAR_H, fill: "url(#" + spec.id + "-hatch)",
                       "pointer-events": "none" }, bars);
        }
        el("title", {}, rect, state + "  " + (spec.frames ? when(spec, iv[0]) + " – " +
           when(spec, iv[1]) : iv[0].toFixed(6) + " – " + iv[1].toFixed(6) + " s") + " (" +
           data.sources[iv[3]] + ")" + (iv[4] ? "\nrebooted " + iv[4] + " time" +
           (iv[4] === 1 ? "" : "s") + " without a state change (boot-up 00h)" : ""));
        if (x1 - x0 > state.length * 6.3 + 10) {
          var lx = (Math.max(x0, LABEL_W) + Math.min(x1, LABEL_W + self.plotW)) / 2;
          el("text", { "class": "iv-label" + (DARK_STATES[state] ? " dark" : ""), x: lx,
                       y: barY + 13, "text-anchor": "middle" }, bars, state);
        }
      });
      // Each boot-up inside a state: a tick across the bar
      (row.boots || []).forEach(function (t) {
        if (t < self.v0 || t > self.v1) { return; }
        var bx = self.x(t);
        var tick = el("line", { "class": "boot-marker", x1: bx, x2: bx, y1: barY - 2,
                                y2: barY + BAR_H + 2 }, bars);
        el("title", {}, tick, "boot-up (00h) at " + when(spec, t));
      });
      // A node-ID assigned by LSS (SPEC §9.4.2): a badge at the boot-up that adopted it;
      // a click shows the configure request on the LSS row
      (row.lss || []).forEach(function (a) {
        if (a[0] < self.v0 || a[0] > self.v1) { return; }
        var ax = self.x(a[0]);
        var badge = el("g", { "class": "lss-adopted", "data-time": a[0], "data-request": a[1] }, bars);
        el("rect", { x: ax, y: barY + 1, width: 22, height: 11, rx: 2 }, badge);
        el("text", { x: ax + 11, y: barY + 10, "text-anchor": "middle" }, badge, "LSS");
        el("title", {}, badge, a[2]);
      });
      // The node's EMCYs (SPEC §9.4.2): a dot on the bar's lower edge coloured by code
      // class, at most one per pixel and class
      var lastDot = {};
      (row.emcy || []).forEach(function (e) {
        var t = e[0];
        if (t < self.v0 || t > self.v1) { return; }
        var ex = self.x(t), cls = data.emcyClasses[e[1]];
        if (lastDot[cls] !== undefined && Math.abs(ex - lastDot[cls]) < 1) { return; }
        lastDot[cls] = ex;
        var dot = el("circle", { "class": "emcy-marker", cx: ex, cy: barY + BAR_H - 3, r: 3.5,
                                 fill: data.emcyColors[cls], "data-class": cls,
                                 "data-time": t }, bars);
        el("title", {}, dot, data.emcyTexts[e[2]] + "\n" + when(spec, t) +
           (e[3] ? " · line " + e[3] : ""));
      });
      // Events that may explain a finding (SPEC §8.6): small grey diamonds in the marker
      // lane, drawn first so the findings' markers stay on top.
      (row.causes || []).forEach(function (cause) {
        var t = cause[0], group = data.groups[cause[1]];
        if (t < self.v0 || t > self.v1) { return; }
        var c = group.occurrences[cause[2]].causes[cause[3]];
        var cx = self.x(t), cy = y0 + MARK_H / 2 + 1;
        var dia = el("polygon", { "class": "cause-marker", "data-group": cause[1],
                                  "data-kind": c.kind,
                                  points: (cx - 3.5) + "," + cy + " " + cx + "," + (cy - 3.5) + " " +
                                          (cx + 3.5) + "," + cy + " " + cx + "," + (cy + 3.5) }, g);
        el("title", {}, dia, "may explain " + group.rule + " " + group.name + " at " +
           group.occurrences[cause[2]].when + "\n" + t.toFixed(6) + " s" +
           (c.end !== null ? " – " + c.end.toFixed(6) + " s" : "") + " · " + c.kind + " · " +
           c.text + (c.line ? " (line " + c.line + ")" : ""));
      });
      row.marks.forEach(function (mark) {
        var t = mark[0], group = data.groups[mark[1]], k = mark[2];
        if (t < self.v0 || t > self.v1) { return; }
        var mx = self.x(t);
        var color = data.severityColors[group.severity];
        var focused = self.focus && self.focus.group === mark[1] && self.focus.k === k;
        el("line", { x1: mx, x2: mx, y1: y0 + MARK_H, y2: barY + BAR_H, stroke: color,
                     "stroke-width": focused ? 2 : 1.2, "pointer-events": "none" }, g);
        var tri = el("polygon", { "class": "marker" + (focused ? " focus" : ""),
                                  points: (mx - 5.5) + "," + (y0 + 1) + " " + (mx + 5.5) + "," +
                                          (y0 + 1) + " " + mx + "," + (y0 + MARK_H + 1),
                                  fill: color, "data-group": mark[1], "data-occurrence": k }, g);
        var occ = group.occurrences[k];
        el("title", {}, tri, group.rule + " " + group.name + " (" + group.severity + ") · " +
           group.where + " · " + when(spec, t) +
           (group.count > 1 ? " · " + (k + 1) + " of " + group.count : "") +
           (occ.line ? " · line " + occ.line : "") + "\n" + occ.message);
      });
    });
    var range = this.figure.querySelector(".tl-range");
    if (range) {
      range.textContent = spec.frames
        ? "frames " + (Math.round(this.v0) + 1) + " – " + (Math.round(this.v1) + 1) + " of " +
          (Math.round(this.total) + 1)
        : this.v0.toFixed(decimals) + " – " + this.v1.toFixed(decimals) + " s of " +
          this.total.toFixed(3) + " s";
    }
  };

  /* The SYNC row (SPEC §9.4.2): the SYNC frames as ticks merged per pixel at the zoom in
     view (runs of columns with frames become one bar), counted bins when the page keeps
     counts only, and each gap over the timeout (Y001) in red. */
  Timeline.prototype.renderSync = function (sync, width, clipId) {
    var self = this, y0 = AXIS_H, barY = y0 + MARK_H + 2, spec = this.spec;
    var g = el("g", { "class": "tl-sync", "data-channel": spec.channel, "data-bar-y": barY,
                      "data-bar-h": BAR_H }, this.svg);
    el("rect", { "class": "row-bg", x: 0, y: y0, width: width, height: ROW_H }, g);
    el("title", {}, el("text", { "class": "row-label", x: 10, y: barY + 13 }, g,
                       "SYNC " + sync.cob_id), sync.title);
    var lane = el("g", { "clip-path": "url(#" + clipId + ")" }, g);
    var runs = [], run = null;
    function column(x0, x1) {  // a stretch with frames, from x0 to x1 (pixels)
      var c0 = Math.floor(x0), c1 = Math.max(Math.floor(x1), c0);
      if (run && c0 <= run[1] + 3) { run[1] = Math.max(run[1], c1); } else { run = [c0, c1]; runs.push(run); }
    }
    function first(list, t) {  // the first index of a sorted list at or after t
      var lo = 0, hi = list.length;
      while (lo < hi) { var mid = (lo + hi) >> 1; if (list[mid] < t) { lo = mid + 1; } else { hi = mid; } }
      return lo;
    }
    if (sync.ticks) {
      for (var k = first(sync.ticks, this.v0); k < sync.ticks.length && sync.ticks[k] <= this.v1; k++) {
        var tx = this.x(sync.ticks[k]);
        column(tx, tx);
      }
    } else if (sync.bins) {
      var b = sync.bins, k0 = Math.max(0, Math.floor((this.v0 - b.t0) / b.width));
      for (var j = k0; j < b.counts.length && b.t0 + j * b.width <= this.v1; j++) {
        if (b.counts[j]) { column(this.x(b.t0 + j * b.width), this.x(b.t0 + (j + 1) * b.width)); }
      }
    }
    runs.forEach(function (r) {
      el("rect", { "class": "sync-tick", x: r[0], y: barY + 4, width: r[1] - r[0] + 1,
                   height: BAR_H - 8 }, lane);
    });
    sync.gaps.forEach(function (gap) {
      if (gap[1] < self.v0 || gap[0] > self.v1) { return; }
      var x0 = Math.max(self.x(gap[0]), LABEL_W - 1);
      var x1 = Math.min(self.x(gap[1]), LABEL_W + self.plotW + 1);
      var ms = (gap[1] - gap[0]) * 1000;
      var rect = el("rect", { "class": "sync-gap", x: x0, y: barY, width: Math.max(x1 - x0, 2),
                              height: BAR_H, "data-start": gap[0], "data-end": gap[1],
                              "data-group": gap[2] === null ? "" : gap[2] }, lane);
      var group = gap[2] === null ? null : data.groups[gap[2]];
      el("title", {}, rect, "no SYNC from " + when(spec, gap[0]) + " to " +
         (gap[4] ? "the end (" + when(spec, gap[1]) + ")" : when(spec, gap[1])) +
         (spec.frames ? "" : ", " + ms.toFixed(3) + " ms") +
         (group ? "\n" + group.rule + " " + group.name + ": " + group.occurrences[gap[3]].message : ""));
      if (x1 - x0 > 90) {
        el("text", { "class": "sync-gap-label", x: (x0 + x1) / 2, y: barY + 13,
                     "text-anchor": "middle" }, lane, spec.frames ? "no SYNC" : "no SYNC " + ms.toFixed(1) + " ms");
      }
    });
  };

  /* The LSS row (SPEC §9.4.2): each LSS session as a pale span, each exchange (request to
     its last answer) as a mark, red where an L001-L006 finding is at it; at the zoom in
     view one mark per pixel and colour (its hover text counts the others there), the red
     ones drawn last. */
  Timeline.prototype.renderLss = function (lss, width, clipId, y0) {
    var self = this, barY = y0 + MARK_H + 2, spec = this.spec;
    var g = el("g", { "class": "tl-lss", "data-channel": spec.channel, "data-bar-y": barY,
                      "data-bar-h": BAR_H }, this.svg);
    el("rect", { "class": "row-bg alt", x: 0, y: y0, width: width, height: ROW_H }, g);
    el("title", {}, el("text", { "class": "row-label", x: 10, y: barY + 13 }, g, "LSS"),
       lss.exchanges.length + " LSS requests drawn" +
       (lss.omitted ? ", " + lss.omitted + " not drawn" : ""));
    var lane = el("g", { "clip-path": "url(#" + clipId + ")" }, g);
    lss.sessions.forEach(function (se) {
      if (se[1] < self.v0 || se[0] > self.v1) { return; }
      var x0 = Math.max(self.x(se[0]), LABEL_W - 1), x1 = Math.min(self.x(se[1]), LABEL_W + self.plotW + 1);
      el("title", {}, el("rect", { "class": "lss-session", x: x0, y: barY, width: Math.max(x1 - x0, 1),
                                   height: BAR_H, "data-start": se[0], "data-end": se[1] }, lane), se[2]);
    });
    [false, true].forEach(function (failed) {
      var last = null;
      lss.exchanges.forEach(function (ex, k) {
        if (ex[2] !== failed || ex[1] < self.v0 || ex[0] > self.v1) { return; }
        var x0 = self.x(ex[0]), x1 = Math.max(self.x(ex[1]), x0 + 3);
        var focused = self.lssFocus !== undefined && self.lssFocus === k;  // always drawn
        if (last && x0 < last.x1 + 1 && !focused) {  // in the mark before: counted there
          last.more += 1;
          last.title.textContent = last.text + "\n(+" + last.more + " more LSS requests here; zoom in)";
          return;
        }
        var mark = el("rect", { "class": "lss-exchange" + (failed ? " failed" : "") + (focused ? " focus" : ""),
                                x: x0 - 1, y: barY + 3, width: x1 - x0, height: BAR_H - 6,
                                "data-start": ex[0], "data-end": ex[1], "data-exchange": k,
                                "data-group": ex[5] === null || ex[5] === undefined ? "" : ex[5] }, lane);
        var lines = data.lssTexts[ex[3]].split("\n");  // the service, then its findings
        lines.splice(1, 0, when(spec, ex[0]) + (ex[4] ? " · line " + ex[4] : ""));
        var text = lines.join("\n");
        last = { x1: x1, more: 0, text: text, title: el("title", {}, mark, text) };
      });
    });
  };

  Timeline.prototype.bind = function () {
    var self = this, svg = this.svg, drag = null;
    svg.addEventListener("wheel", function (e) {
      var t = self.timeAt(e.clientX);
      if (t < self.v0 || t > self.v1) { return; }  // over the labels: let the page scroll
      e.preventDefault();
      self.zoom(e.deltaY < 0 ? 1 / 1.3 : 1.3, t);
    }, { passive: false });
    svg.addEventListener("pointerdown", function (e) {
      drag = { x: e.clientX, v0: self.v0, v1: self.v1, moved: false, id: e.pointerId };
    });
    svg.addEventListener("pointermove", function (e) {
      if (!drag) { return; }
      var dx = e.clientX - drag.x;
      if (!drag.moved && Math.abs(dx) > 3) {
        drag.moved = true;
        svg.setPointerCapture(drag.id);
        svg.classList.add("dragging");
      }
      if (drag.moved) {
        var dt = -dx / self.plotW * (drag.v1 - drag.v0);
        self.setView(drag.v0 + dt, drag.v1 + dt);
      }
    });
    function endDrag() {
      if (drag && drag.moved) { svg.classList.remove("dragging"); }
      window.setTimeout(function () { drag = null; }, 0);
    }
    svg.addEventListener("pointerup", endDrag);
    svg.addEventListener("pointercancel", endDrag);
    svg.addEventListener("dblclick", function () { self.setView(0, self.total); });
    svg.addEventListener("click", function (e) {
      if (drag && drag.moved) { return; }
      var badge = e.target.closest ? e.target.closest(".lss-adopted") : null;
      if (badge) { self.showLss(Number(badge.getAttribute("data-request"))); return; }
      var marker = e.target.closest ? e.target.closest(".marker, .cause-marker, .sync-gap, .lss-exchange") : null;
      if (marker && marker.getAttribute("data-group")) { showFinding(marker.getAttribute("data-group")); }
    });
    this.figure.querySelectorAll("button[data-zoom]").forEach(function (button) {
      button.addEventListener("click", function () {
        var how = button.getAttribute("data-zoom");
        if (how === "fit") { self.setView(0, self.total); } else { self.zoom(how === "in" ? 0.5 : 2); }
      });
    });
  };

  /* Zoom to a finding's moment (a window of an eighth of the recording, or the current
     one if that is narrower) and mark it. */
  Timeline.prototype.showMoment = function (groupId, k) {
    // a later capture's timeline counts from its own first frame (spec.shift seconds later)
    var t = data.groups[groupId].occurrences[k].time - (this.spec.shift || 0);
    var span = Math.min(this.v1 - this.v0, Math.max(this.total / 8, 0.01));
    this.focus = { group: groupId, k: k };
    this.setView(t - span / 2, t + span / 2);
    this.figure.scrollIntoView({ block: "center" });
  };

  /* Zoom to the LSS request at t (a node-ID's origin) and mark it on the LSS row. */
  Timeline.prototype.showLss = function (t) {
    var found = -1;
    (this.spec.lss ? this.spec.lss.exchanges : []).forEach(function (ex, k) {
      if (found < 0 && Math.abs(ex[0] - t) < 1e-6) { found = k; }
    });
    var span = Math.min(this.v1 - this.v0, Math.max(this.total / 8, 0.01));
    this.focus = null;
    this.lssFocus = found < 0 ? undefined : found;
    this.setView(t - span / 2, t + span / 2);
  };

  /* Zoom to a moment t (a chain's entry) as showMoment does, without a finding to mark. */
  Timeline.prototype.showTime = function (t) {
    var span = Math.min(this.v1 - this.v0, Math.max(this.total / 8, 0.01));
    this.focus = null;
    this.setView(t - span / 2, t + span / 2);
    this.figure.scrollIntoView({ block: "center" });
  };

  function showFinding(groupId) {
    var row = document.getElementById("finding-" + groupId);
    if (!row) { return; }
    if (row.hidden) { resetFilters(); }
    row.scrollIntoView({ block: "center" });
    row.classList.add("flash");
    window.setTimeout(function () { row.classList.remove("flash"); }, 1600);
  }

  /* Findings table: filters by rule, node, severity and text; sort by any header. */
  var table = document.getElementById("findings-table");
  var filterIds = ["filter-rule", "filter-node", "filter-severity", "filter-text"];

  function applyFilters() {
    if (!table) { return; }
    var rule = document.getElementById("filter-rule").value;
    var node = document.getElementById("filter-node").value;
    var severity = document.getElementById("filter-severity").value;
    var text = document.getElementById("filter-text").value.trim().toLowerCase();
    var rows = table.tBodies[0].rows, shown = 0;
    for (var i = 0; i < rows.length; i++) {
      var r = rows[i];
      var ok = (!rule || r.dataset.rule === rule) && (!node || r.dataset.node === node) &&
               (!severity || r.dataset.severity === severity) &&
               (!text || r.textContent.toLowerCase().indexOf(text) >= 0);
      r.hidden = !ok;
      if (ok) { shown++; }
    }
    document.getElementById("filter-count").textContent = shown + " of " + rows.length + " rows";
  }

  function resetFilters() {
    filterIds.forEach(function (id) { document.getElementById(id).value = ""; });
    applyFilters();
  }

  function sortBy(th) {
    var key = "sort" + th.dataset.sort.charAt(0).toUpperCase() + th.dataset.sort.slice(1);
    var ascending = th.getAttribute("aria-sort") !== "ascending";
    table.querySelectorAll("th.sort").forEach(function (h) { h.removeAttribute("aria-sort"); });
    th.setAttribute("aria-sort", ascending ? "ascending" : "descending");
    var body = table.tBodies[0];
    var rows = Array.prototype.slice.call(body.rows);
    var numeric = rows.every(function (r) { return r.dataset[key] !== "" && !isNaN(Number(r.dataset[key])); });
    rows.sort(function (a, b) {
      var x = a.dataset[key], y = b.dataset[key];
      var c = numeric ? Number(x) - Number(y) : x.localeCompare(y);
      return ascending ? c : -c;
    });
    rows.forEach(function (r) { body.appendChild(r); });
  }

  if (table) {
    filterIds.forEach(function (id) {
      var input = document.getElementById(id);
      input.addEventListener(input.tagName === "SELECT" ? "change" : "input", applyFilters);
    });
    table.querySelectorAll("th.sort").forEach(function (th) {
      th.addEventListener("click", function () { sortBy(th); });
    });
  }

  document.addEventListener("click", function (e) {
    var link = e.target.closest ? e.target.closest("a.jump, a.rule-link, a.cause-jump") : null;
    if (!link) { return; }
    if (link.classList.contains("cause-jump")) {  // a chain's entry: its moment (SPEC §9.3.6)
      var shown = timelines[link.getAttribute("data-timeline")];
      if (shown) {
        e.preventDefault();
        shown.showTime(Number(link.getAttribute("data-time")) - (shown.spec.shift || 0));
      }
      return;
    }
    if (link.classList.contains("rule-link")) {
      var details = document.getElementById(link.getAttribute("href").slice(1));
      if (details) { details.open = true; }
      return;
    }
    var groupId = link.getAttribute("data-jump");
    var timeline = timelines[data.groups[groupId].timeline];
    if (timeline) {
      e.preventDefault();
      timeline.showMoment(groupId, Number(link.getAttribute("data-occurrence")));
    }
  });

  function openRuleFromHash() {
    if (location.hash.indexOf("#rule-") === 0) {
      var details = document.getElementById(location.hash.slice(1));
      if (details) { details.open = true; }
    }
  }

  data.timelines.forEach(function (spec) {
    var figure = document.getElementById(spec.id);
    if (figure && figure.querySelector("svg.tl-svg")) { timelines[spec.id] = new Timeline(figure, spec); }
  });
  window.addEventListener("resize", function () {
    Object.keys(timelines).forEach(function (id) { timelines[id].scheduleRender(); });
  });
  window.addEventListener("hashchange", openRuleFromHash);
  openRuleFromHash();
  window.nmtReport = { timelines: timelines, applyFilters: applyFilters, data: data };
}());
