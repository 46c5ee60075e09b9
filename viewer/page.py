# ruff: noqa: E501 - the page's inline JavaScript keeps its own line lengths
"""The built-in page: one HTML document with inline CSS and JavaScript, drawn on canvases.

Nothing to install and nothing fetched from elsewhere (no CDN): the page polls ``/state`` of the
server that served it about ten times a second and draws

* the floor seen from above, fitted to the fleet and following it: blind floor where the camera
  sees no robot (violet, translucent), obstacles (grey, with a ring at their safe distance),
  walls and shelves, a lifelong run's loads on the floor (brown boxes while resting, in the
  team's colour while carried, each named), each leader's planned route (dotted, waypoints as
  small squares), formation ellipses, each formation's load under its robots (hatched when
  declared, lightly filled with a dashed edge for the members' hull), goals (squares), robots
  (discs in their formation's colour, a heading tick, the control point when it is off the
  centre), under ``fused`` each robot's own estimate over its body (a white dot, a dashed dark
  ring of its 95 % confidence radius around it, a thin line to the true body's centre), and a red line for each load
  overlap (held for a second of shown time);
* each robot's smallest barrier value of each kind since the run started (at most the last
  ten minutes, at least a minute wide; three charts, zero marked): the page fetches the
  server's history (``GET /history``) once when it loads, so a reloaded page plots the run from
  its start, then adds what it polls;
* each formation's status (as its leader reports it: state and why, distance to go, waypoint,
  leader, the goals it refused and why it refused the last one), a lifelong run's orders (the
  count per state, then each open or recently ended order: state, since when, from, to, team,
  why it failed),
  each robot's QP status, slack and barrier values (and under ``fused`` its 95 % radius),
  the newest log lines, the shown time (simulated seconds; for wall
  time the UTC clock and the seconds since the first frame), the Foxglove WebSocket's port;
* for a replay: play/pause, speed and a time slider.

For tests and scripts the page exposes ``window.viewer`` (shown time, sequence number, each
robot's and load's projected position and each load overlap's line in CSS pixels of the
viewport; ``estimates``, ``blind`` and ``cargo``: each estimate's centre and ring radius, each
blind box's and each lifelong load's centre, likewise; ``orders``: the orders listed; and
``history``: the oldest time and the number of points the barrier charts hold),
``window.chartAxes`` (the charts' time span and where they are in the viewport) and keeps the
shown time in
``document.title`` and in ``#time``; ``window.viewerFreeze = true`` stops redrawing.
"""

from __future__ import annotations

import html
import json

PALETTE = ("#1f77b4", "#d62728", "#2ca02c", "#9467bd", "#ff7f0e", "#8c564b", "#e377c2", "#17becf")

_PAGE = r"""<!doctype html>
<html lang="en"><head><meta charset="utf-8">
<title>formation view</title>
<style>
 body { font: 13px/1.35 system-ui, sans-serif; margin: 8px; background: #fafafa; color: #222; }
 #wrap { display: flex; gap: 12px; align-items: flex-start; }
 canvas { background: #fff; border: 1px solid #ccc; display: block; }
 #side { min-width: 300px; max-width: 420px; }
 table { border-collapse: collapse; margin: 4px 0 8px; }
 td, th { padding: 1px 6px; border-bottom: 1px solid #eee; text-align: left; }
 #time { font-size: 20px; font-weight: 600; }
 #logs { font-family: monospace; font-size: 11px; max-height: 220px; overflow-y: auto;
         white-space: pre-wrap; background: #fff; border: 1px solid #ddd; padding: 4px; }
 .warning { color: #a60; } .error { color: #c00; }
 #controls { display: none; margin: 6px 0; }
 .sw { display: inline-block; width: 10px; height: 10px; margin-right: 4px; }
 .order.failed { color: #c00; } .order.delivered { color: #2a7a2a; }
</style></head>
<body>
<div id="wrap">
 <div>
  <canvas id="floor" width="720" height="540"></canvas>
  <canvas id="chart" width="720" height="270"></canvas>
 </div>
 <div id="side">
  <div id="time">waiting for the fleet...</div>
  <div id="meta"></div>
  <div id="controls">
   <button id="play">pause</button>
   speed <select id="speed"></select>
   <input id="seek" type="range" min="0" max="1000" value="0" style="width: 220px">
  </div>
  <h4>Formations</h4><table id="formations"></table>
  <div id="orders-box" style="display: none"><h4>Orders</h4><div id="order-counts"></div><table id="orders"></table></div>
  <h4>Robots</h4><table id="robots"></table>
  <h4>Log</h4><div id="logs"></div>
 </div>
</div>
<script>
"use strict";
const PALETTE = __PALETTE__;
const KINDS = ["formation", "obstacle", "formations"];
const WINDOW_S = 60;  // [s] the charts are at least this wide, and at most historySpan
const floor = document.getElementById("floor"), fctx = floor.getContext("2d");
const chart = document.getElementById("chart"), cctx = chart.getContext("2d");
const HIT_HOLD_S = 1.0;
let view = null, history = {}, lastT = null, lastSeq = -1, colors = {}, state = null, t0 = null;
let historySpan = 600;  // [s] the server's (GET /history span_s)
let hatches = {}, recentHits = {};
window.viewer = { t: null, seq: -1, robots: [], loads: [], hits: [], estimates: [], blind: [], cargo: [], orders: [] };
window.viewerFreeze = false;

function colorOf(formation) {
  if (!(formation in colors)) colors[formation] = PALETTE[Object.keys(colors).length % PALETTE.length];
  return colors[formation];
}
function finite(v) { return typeof v === "number" && isFinite(v); }

function fit(frame) {
  // the box around every robot, ellipse and lifelong load, with a margin, at least 4 m across
  let x0 = Infinity, y0 = Infinity, x1 = -Infinity, y1 = -Infinity;
  const add = (x, y, r) => { x0 = Math.min(x0, x - r); x1 = Math.max(x1, x + r);
                             y0 = Math.min(y0, y - r); y1 = Math.max(y1, y + r); };
  for (const r of frame.robots) if (finite(r.x)) add(r.x, r.y, 1.0);
  for (const e of frame.ellipses) if (finite(e.cx)) add(e.cx, e.cy, Math.max(e.a, e.b) + 0.5);
  for (const ld of frame.cargo || []) for (const p of ld.outline) if (finite(p[0])) add(p[0], p[1], 0.5);
  if (!isFinite(x0)) return view;
  const cx = (x0 + x1) / 2, cy = (y0 + y1) / 2;
  const w = Math.max(x1 - x0, 4, (y1 - y0) * floor.width / floor.height);
  const target = { cx: cx, cy: cy, s: floor.width / w };
  if (!view) return target;
  const k = 0.25;  // follow smoothly
  return { cx: view.cx + k * (target.cx - view.cx), cy: view.cy + k * (target.cy - view.cy),
           s: view.s + k * (target.s - view.s) };
}
function px(x, y) { return [floor.width / 2 + (x - view.cx) * view.s,
                            floor.height / 2 - (y - view.cy) * view.s]; }

function niceStep(m) {  // the smallest of 1, 2, 5 x 10^k metres at least m
  const p = Math.pow(10, Math.floor(Math.log10(m)));
  for (const k of [1, 2, 5, 10]) if (k * p >= m) return k * p;
  return 10 * p;
}
function drawAxes(c, gx0, gx1, gy0, gy1) {
  // metric axes: x labels along the bottom edge, y labels along the left, every `step` metres
  const step = niceStep(40 / view.s), H = floor.height;
  c.fillStyle = "#666"; c.font = "10px sans-serif";
  for (let g = Math.ceil(gx0 / step) * step; g <= gx1; g += step) {
    const [a] = px(g, 0); c.fillText(+g.toFixed(3) + "", a + 2, H - 4);
  }
  for (let g = Math.ceil(gy0 / step) * step; g <= gy1; g += step) {
    const [, b] = px(0, g); c.fillText(+g.toFixed(3) + "", 2, b - 2);
  }
  c.fillText("x [m]", floor.width / 2, H - 16); c.fillText("y [m]", 2, 12);
  // scale bar, bottom right: a round length of about 100 px
  const len = niceStep(100 / view.s), w = len * view.s, x1 = floor.width - 12, y = H - 22;
  c.strokeStyle = "#222"; c.lineWidth = 3;
  c.beginPath(); c.moveTo(x1 - w, y); c.lineTo(x1, y); c.stroke();
  c.lineWidth = 1; c.beginPath(); c.moveTo(x1 - w, y - 5); c.lineTo(x1 - w, y + 5); c.moveTo(x1, y - 5); c.lineTo(x1, y + 5); c.stroke();
  c.fillStyle = "#222"; c.font = "11px sans-serif";
  const label = len + " m"; c.fillText(label, x1 - w / 2 - c.measureText(label).width / 2, y - 6);
  c.strokeStyle = "#eee";
  const rect = floor.getBoundingClientRect(), sx = rect.width / floor.width, sy = rect.height / floor.height;
  window.floorAxes = { step: step, bar_m: len, bar_px: w, scale: view.s,  // for tests: where the bar is on screen
                       bar_left: rect.left + (x1 - w) * sx, bar_right: rect.left + x1 * sx, bar_y: rect.top + y * sy };
}

function drawFloor(frame) {
  view = fit(frame);
  const c = fctx;
  c.clearRect(0, 0, floor.width, floor.height);
  // 1 m grid
  c.strokeStyle = "#eee"; c.lineWidth = 1;
  const gx0 = Math.floor(view.cx - floor.width / 2 / view.s), gx1 = Math.ceil(view.cx + floor.width / 2 / view.s);
  const gy0 = Math.floor(view.cy - floor.height / 2 / view.s), gy1 = Math.ceil(view.cy + floor.height / 2 / view.s);
  for (let g = gx0; g <= gx1; g++) { const [a] = px(g, 0); c.beginPath(); c.moveTo(a, 0); c.lineTo(a, floor.height); c.stroke(); }
  for (let g = gy0; g <= gy1; g++) { const [, b] = px(0, g); c.beginPath(); c.moveTo(0, b); c.lineTo(floor.width, b); c.stroke(); }
  const rad = frame.radius || 0.105;
  const blind = drawBlind(c, frame.blind || []);
  for (const o of frame.obstacles) {
    if (!finite(o.x)) continue;
    const [a, b] = px(o.x, o.y);
    c.fillStyle = "#888"; c.beginPath(); c.arc(a, b, Math.max(o.ds - rad, 0.05) * view.s, 0, 2 * Math.PI); c.fill();
    c.strokeStyle = "#e5602a"; c.setLineDash([5, 4]); c.beginPath(); c.arc(a, b, o.ds * view.s, 0, 2 * Math.PI); c.stroke();
    c.setLineDash([]);
  }
  for (const s of frame.shapes || []) {  // walls (2 corners) and shelves (4), Ds dashed around
    const pts = s.corners.filter(p => finite(p[0])).map(p => px(p[0], p[1]));
    if (pts.length < 2) continue;
    c.beginPath(); c.moveTo(pts[0][0], pts[0][1]);
    for (const p of pts.slice(1)) c.lineTo(p[0], p[1]);
    if (s.kind === "box") { c.closePath(); c.fillStyle = "#999"; c.fill(); }
    else { c.strokeStyle = "#555"; c.lineWidth = 3; c.stroke(); c.lineWidth = 1; }
  }
  const cargo = drawCargo(c, frame.cargo || []);
  for (const rt of frame.routes || []) {  // each leader's planned route, dashed, its goal last
    const pts = rt.points.filter(p => finite(p[0])).map(p => px(p[0], p[1]));
    if (pts.length < 1) continue;
    c.strokeStyle = colorOf(rt.formation); c.setLineDash([2, 6]); c.lineWidth = 2;
    c.beginPath(); c.moveTo(pts[0][0], pts[0][1]);
    for (const p of pts.slice(1)) c.lineTo(p[0], p[1]);
    c.stroke(); c.setLineDash([]); c.lineWidth = 1;
    for (const p of pts) { c.fillStyle = colorOf(rt.formation); c.fillRect(p[0] - 2, p[1] - 2, 4, 4); }
  }
  for (const e of frame.ellipses) {
    if (!finite(e.cx) || !finite(e.a)) continue;
    const [a, b] = px(e.cx, e.cy);
    c.strokeStyle = colorOf(e.formation); c.lineWidth = 2;
    c.beginPath(); c.ellipse(a, b, e.a * view.s, e.b * view.s, -e.alpha, 0, 2 * Math.PI); c.stroke();
  }
  c.lineWidth = 1;
  const loads = drawLoads(c, frame.loads || []);
  for (const r of frame.robots) {
    if (!finite(r.gx)) continue;
    const [a, b] = px(r.gx, r.gy);
    c.strokeStyle = colorOf(r.formation); c.strokeRect(a - 4, b - 4, 8, 8);
  }
  const shown = [];
  const rect = floor.getBoundingClientRect(), sx = rect.width / floor.width, sy = rect.height / floor.height;
  for (const r of frame.robots) {
    if (!finite(r.x)) continue;
    const [a, b] = px(r.x, r.y), rr = Math.max(rad * view.s, 4), col = colorOf(r.formation);
    c.fillStyle = col; c.beginPath(); c.arc(a, b, rr, 0, 2 * Math.PI); c.fill();
    const th = r.theta || 0;
    c.strokeStyle = "#111"; c.lineWidth = 2; c.beginPath();
    c.moveTo(a + 0.55 * rr * Math.cos(th), b - 0.55 * rr * Math.sin(th));
    c.lineTo(a + 1.5 * rr * Math.cos(th), b - 1.5 * rr * Math.sin(th)); c.stroke(); c.lineWidth = 1;
    if (finite(r.px) && Math.hypot(r.px - r.x, r.py - r.y) > 0.025) {  // a look-ahead point, not a state lagging the pose
      const [qa, qb] = px(r.px, r.py);
      c.fillStyle = "#fff"; c.beginPath(); c.arc(qa, qb, 2.5, 0, 2 * Math.PI); c.fill();
    }
    if (r.status && r.status !== "ok") {
      c.strokeStyle = r.status === "relaxed" ? "#e0a000" : "#c00"; c.lineWidth = 3;
      c.beginPath(); c.arc(a, b, rr + 3, 0, 2 * Math.PI); c.stroke(); c.lineWidth = 1;
    }
    c.fillStyle = "#222"; c.font = "11px sans-serif"; c.fillText(r.id, a + rr + 2, b - rr - 2);
    shown.push({ id: r.id, x: r.x, y: r.y, color: col,
                 cx: rect.left + a * sx, cy: rect.top + b * sy, r: rr * sx });
  }
  const estimates = drawEstimates(c, frame.robots);  // over the bodies: a ring is often smaller than one
  const hits = drawHits(c, frame);
  drawAxes(c, gx0, gx1, gy0, gy1);  // last: on top of shelves and robots
  return { robots: shown, loads: loads, hits: hits, estimates: estimates, blind: blind, cargo: cargo };
}

function centre(pts) {
  return [pts.reduce((s, p) => s + p[0], 0) / pts.length, pts.reduce((s, p) => s + p[1], 0) / pts.length];
}
function outlinePath(c, pts) {
  c.beginPath(); c.moveTo(pts[0][0], pts[0][1]);
  for (const p of pts.slice(1)) c.lineTo(p[0], p[1]);
  c.closePath();
}
function drawBlind(c, boxes) {  // floor the camera cannot see: violet, translucent, under everything
  const out = [];
  for (const b of boxes) {
    const pts = b.corners.filter(p => finite(p[0])).map(p => px(p[0], p[1]));
    if (pts.length < 3) continue;
    outlinePath(c, pts);
    c.fillStyle = "rgba(140, 90, 190, 0.16)"; c.fill();
    c.strokeStyle = "rgba(140, 90, 190, 0.8)"; c.setLineDash([3, 3]); c.stroke(); c.setLineDash([]);
    const [a, b2] = centre(pts), [sx, sy] = toScreen(a, b2);
    c.fillStyle = "rgba(110, 60, 160, 0.9)"; c.font = "10px sans-serif"; c.fillText("blind", a - 12, b2 + 3);
    out.push({ cx: sx, cy: sy });
  }
  return out;
}
function drawCargo(c, cargo) {  // a lifelong run's loads: brown resting, the team's colour carried
  const out = [];
  for (const ld of cargo) {
    const pts = ld.outline.filter(p => finite(p[0])).map(p => px(p[0], p[1]));
    if (pts.length < 3) continue;
    const carried = ld.state === "carried", col = carried ? colorOf(ld.order) : "#8c6239";
    outlinePath(c, pts);
    c.globalAlpha = carried ? 0.35 : 0.75; c.fillStyle = col; c.fill(); c.globalAlpha = 1;
    c.strokeStyle = carried ? col : "#5a3d1e"; c.lineWidth = 2; c.stroke(); c.lineWidth = 1;
    const [a, b] = centre(pts), [sx, sy] = toScreen(a, b);
    c.fillStyle = "#222"; c.font = "10px sans-serif"; c.fillText(ld.name, a - 3 * ld.name.length, b + 3);
    out.push({ name: ld.name, state: ld.state, order: ld.order, color: col, cx: sx, cy: sy });
  }
  return out;
}
function drawEstimates(c, robots) {
  // under fused: each robot's own estimate, its 95 % confidence ring (dashed) and a thin line to the true body
  const out = [];
  for (const r of robots) {
    if (!finite(r.est_x) || !finite(r.sigma_m) || !finite(r.x)) continue;
    const [a, b] = px(r.est_x, r.est_y), [ta, tb] = px(r.x, r.y), col = colorOf(r.formation);
    const rr = Math.max(r.sigma_m * view.s, 2);
    c.strokeStyle = "#111"; c.lineWidth = 1.5; c.setLineDash([4, 3]);
    c.beginPath(); c.arc(a, b, rr, 0, 2 * Math.PI); c.stroke(); c.setLineDash([]);
    c.lineWidth = 1; c.beginPath(); c.moveTo(ta, tb); c.lineTo(a, b); c.stroke();
    c.fillStyle = "#fff"; c.beginPath(); c.arc(a, b, 2.5, 0, 2 * Math.PI); c.fill(); c.stroke();
    const [sx, sy] = toScreen(a, b), rect = floor.getBoundingClientRect();
    out.push({ id: r.id, color: col, cx: sx, cy: sy, r: rr * rect.width / floor.width, sigma_m: r.sigma_m });
  }
  return out;
}

function hatch(color) {  // diagonal stripes in a formation's colour: a declared load's fill
  if (hatches[color]) return hatches[color];
  const t = document.createElement("canvas"); t.width = t.height = 8;
  const g = t.getContext("2d");
  g.fillStyle = color; g.globalAlpha = 0.18; g.fillRect(0, 0, 8, 8);
  g.globalAlpha = 0.6; g.strokeStyle = color; g.lineWidth = 1.5;
  g.beginPath(); g.moveTo(-2, 10); g.lineTo(10, -2); g.moveTo(-2, 2); g.lineTo(2, -2); g.moveTo(6, 10); g.lineTo(10, 6); g.stroke();
  return (hatches[color] = fctx.createPattern(t, "repeat"));
}
function toScreen(a, b) {  // canvas pixels -> CSS pixels of the viewport (for tests)
  const rect = floor.getBoundingClientRect();
  return [rect.left + a * rect.width / floor.width, rect.top + b * rect.height / floor.height];
}
function drawLoads(c, loads) {
  // each formation's load under its robots: a declared one hatched with a solid edge, the
  // default hull of its members lightly filled with a dashed edge (a pair's: a wide band)
  const out = [];
  for (const ld of loads) {
    const pts = ld.outline.filter(p => finite(p[0])).map(p => px(p[0], p[1]));
    if (pts.length < 2) continue;
    const col = colorOf(ld.formation);
    c.beginPath(); c.moveTo(pts[0][0], pts[0][1]);
    for (const p of pts.slice(1)) c.lineTo(p[0], p[1]);
    if (pts.length === 2) {
      c.strokeStyle = col; c.globalAlpha = 0.3; c.lineWidth = Math.max(0.1 * view.s, 4); c.stroke();
    } else {
      c.closePath(); c.globalAlpha = 1; c.fillStyle = ld.declared ? hatch(col) : col;
      if (!ld.declared) c.globalAlpha = 0.15;
      c.fill(); c.globalAlpha = 1; c.strokeStyle = col; c.lineWidth = ld.declared ? 2 : 1;
      if (!ld.declared) c.setLineDash([6, 4]);
      c.stroke(); c.setLineDash([]);
    }
    c.globalAlpha = 1; c.lineWidth = 1;
    const cx = pts.reduce((s, p) => s + p[0], 0) / pts.length, cy = pts.reduce((s, p) => s + p[1], 0) / pts.length;
    const [sx, sy] = toScreen(cx, cy);
    out.push({ formation: ld.formation, declared: ld.declared, color: col, cx: sx, cy: sy });
  }
  return out;
}
function drawHits(c, frame) {
  // each load overlap: a red line from the load's edge to what it overlaps, held on the floor
  // for HIT_HOLD_S of the shown time so a one-tick touch is seen at ten polls a second
  for (const h of frame.load_hits || []) recentHits[h.formation + "/" + h.other] = { t: frame.t, h: h };
  const out = [];
  for (const key in recentHits) {
    const e = recentHits[key];
    if (e.t > frame.t || e.t < frame.t - HIT_HOLD_S) { delete recentHits[key]; continue; }
    const [a, b] = px(e.h.line[0][0], e.h.line[0][1]), [d, f] = px(e.h.line[1][0], e.h.line[1][1]);
    c.strokeStyle = "#d00000"; c.lineWidth = 3;
    c.beginPath(); c.moveTo(a, b); c.lineTo(d, f); c.stroke();
    c.fillStyle = "#d00000"; c.beginPath(); c.arc(a, b, 4, 0, 2 * Math.PI); c.fill(); c.lineWidth = 1;
    const [sa, sb] = toScreen(a, b), [sd, sf] = toScreen(d, f);
    out.push({ formation: e.h.formation, other: e.h.other, ax: sa, ay: sb, bx: sd, by: sf });
  }
  return out;
}

function chartSpan(t1) {
  // from the oldest point held (the run's start, or historySpan ago) to now, at least WINDOW_S
  let start = t1;
  for (const id in history) { const p = history[id].pts; if (p.length && p[0][0] < start) start = p[0][0]; }
  return Math.max(t1 - Math.max(start, t1 - historySpan), WINDOW_S);
}
function drawChart(frame) {
  const c = cctx, W = chart.width, H = chart.height / KINDS.length;
  c.clearRect(0, 0, W, chart.height);
  const t1 = frame.t, span = chartSpan(t1), t0 = t1 - span;
  const rect = chart.getBoundingClientRect();
  window.chartAxes = { t0: t0, t1: t1, left: rect.left, top: rect.top, width: rect.width, height: rect.height };
  KINDS.forEach((kind, k) => {
    const top = k * H;
    let lo = 0, hi = 0.1;
    for (const id in history) for (const p of history[id].pts) {
      const v = p[k + 1]; if (finite(v)) { lo = Math.min(lo, v); hi = Math.max(hi, v); } }
    hi = Math.min(hi, Math.max(lo + 0.1, 5)); // far-away barriers would flatten the rest
    const y = v => top + H - 14 - (Math.min(v, hi) - lo) / (hi - lo) * (H - 24);
    c.strokeStyle = "#ddd"; c.strokeRect(0.5, top + 0.5, W - 1, H - 1);
    c.strokeStyle = "#c00"; c.setLineDash([4, 3]); c.beginPath(); c.moveTo(0, y(0)); c.lineTo(W, y(0)); c.stroke(); c.setLineDash([]);
    c.fillStyle = "#333"; c.font = "11px sans-serif";
    c.fillText("min h_" + kind + "  [" + lo.toFixed(2) + ", " + hi.toFixed(2) + "]  over the last " + span.toFixed(0) + " s", 6, top + 12);
    for (const id in history) {
      const h = history[id]; c.strokeStyle = colorOf(h.formation); c.beginPath();
      let pen = false;
      for (const p of h.pts) {
        const v = p[k + 1];
        if (!finite(v) || p[0] < t0) { pen = false; continue; }
        const X = (p[0] - t0) / span * W, Y = y(v);
        if (pen) c.lineTo(X, Y); else c.moveTo(X, Y);
        pen = true;
      }
      c.stroke();
    }
  });
}

function record(frame) {
  if (lastT !== null && frame.t < lastT) history = {};  // a replay jumped back
  lastT = frame.t;
  for (const r of frame.robots) {
    const h = history[r.id] || (history[r.id] = { formation: r.formation, pts: [] });
    h.formation = r.formation;
    if (h.pts.length && h.pts[h.pts.length - 1][0] >= frame.t) continue;  // had it from /history
    h.pts.push([frame.t, r.h_formation, r.h_obstacle, r.h_formations]);
    while (h.pts.length && h.pts[0][0] < frame.t - historySpan) h.pts.shift();
  }
}
function historyStats() {
  let start = null, points = 0;
  for (const id in history) {
    const p = history[id].pts; points += p.length;
    if (p.length && (start === null || p[0][0] < start)) start = p[0][0];
  }
  return { start: start, points: points };
}
async function loadHistory() {
  // what the server kept since the run started (or its last historySpan s): a reload keeps the plots
  try {
    const h = await (await fetch("/history", { cache: "no-store" })).json();
    if (finite(h.span_s)) historySpan = h.span_s;
    history = h.robots || {};
    for (const id in history) { const p = history[id].pts; if (p.length) lastT = Math.max(lastT === null ? -Infinity : lastT, p[p.length - 1][0]); }
  } catch (err) {
    document.getElementById("meta").textContent = "no history: " + err;
  }
}

function clock(t) { return t > 1e8 ? new Date(t * 1000).toISOString().substring(11, 22) : t.toFixed(2); }
function fmt(v, d) { return finite(v) ? v.toFixed(d) : "-"; }
function esc(s) { return String(s).replace(/[&<>]/g, ch => ({"&": "&amp;", "<": "&lt;", ">": "&gt;"})[ch]); }

function side(st) {
  const f = st.frame;
  // simulated seconds, or wall time (a real fleet, a real-time run): then the clock and the run's
  // time, from the server's first frame (f.t0: the run's start for run --live; kept over a reload)
  if (t0 === null || f.t < t0) t0 = f.t;
  const start = finite(f.t0) ? f.t0 : t0;
  document.getElementById("time").textContent = f.t > 1e8
    ? new Date(f.t * 1000).toISOString().substring(11, 22) + " UTC  (run time " + (f.t - start).toFixed(2) + " s)"
    : "t = " + f.t.toFixed(2) + " s";
  document.title = "formation " + st.mode + " t=" + f.t.toFixed(2);
  const ws = st.ws_port ? ("Foxglove WebSocket: ws://" + location.hostname + ":" + st.ws_port) : "";
  document.getElementById("meta").textContent = st.mode + "  " + ws;
  let rows = "<tr><th>formation</th><th>status</th><th>QP</th><th>to go [m]</th><th>waypoint</th><th>leader</th><th>goals refused</th></tr>";
  for (const fm of f.formations) rows += "<tr><td><span class='sw' style='background:" + colorOf(fm.name) +
    "'></span>" + esc(fm.name) + "</td><td>" + esc(fm.status) + (fm.reason ? " (" + esc(fm.reason) + ")" : "") +
    "</td><td>" + esc(fm.qp) + "</td><td>" + fmt(fm.distance, 2) +
    "</td><td>" + esc(fm.waypoint || "") + "</td><td>" + esc(fm.leader || "") + "</td><td class='refused'>" +
    (fm.refused ? fm.refused + (fm.refusal ? ", the last: " + esc(fm.refusal) : "") : "") + "</td></tr>";
  document.getElementById("formations").innerHTML = rows;
  sideOrders(f);
  const fused = f.robots.some(r => finite(r.sigma_m));  // its own estimate: the 95 % radius too
  rows = "<tr><th>robot</th><th>QP</th><th>slack</th><th>h_form</th><th>h_obs</th><th>h_ell</th>" +
    (fused ? "<th>radius [cm]</th>" : "") + "</tr>";
  for (const r of f.robots) rows += "<tr><td>" + esc(r.id) + "</td><td>" + esc(r.status) + "</td><td>" + fmt(r.slack, 3) +
    "</td><td>" + fmt(r.h_formation, 3) + "</td><td>" + fmt(r.h_obstacle, 3) + "</td><td>" + fmt(r.h_formations, 3) +
    (fused ? "</td><td class='radius'>" + fmt(100 * r.sigma_m, 1) : "") + "</td></tr>";
  document.getElementById("robots").innerHTML = rows;
  document.getElementById("logs").innerHTML = st.logs.slice().reverse().map(e =>
    "<div class='" + esc(e.level) + "'>" + clock(e.t) + " " + esc(e.name) + ": " + esc(e.message) + "</div>").join("");
  const pb = st.playback;
  if (st.mode === "replay" && pb && pb.end !== undefined) {
    document.getElementById("controls").style.display = "block";
    document.getElementById("play").textContent = pb.playing ? "pause" : "play";
    const sel = document.getElementById("speed");
    if (!sel.options.length) for (const s of [0.25, 0.5, 1, 2, 4, 8, 16]) sel.add(new Option(s + "x", s));
    sel.value = String(pb.speed);
    const span = Math.max(pb.end - pb.start, 1e-9);
    document.getElementById("seek").value = Math.round((pb.time - pb.start) / span * 1000);
  }
}

function sideOrders(f) {  // a lifelong run's orders: the count per state, then the listed ones
  const box = document.getElementById("orders-box");
  if (!f.orders) { box.style.display = "none"; return; }
  box.style.display = "block";
  const counts = f.order_counts || {};
  document.getElementById("order-counts").textContent = Object.keys(counts).map(k => counts[k] + " " + k).join(", ");
  let rows = "<tr><th>order</th><th>state</th><th>since [s]</th><th>from</th><th>to</th><th>team</th></tr>";
  for (const o of f.orders) rows += "<tr class='order " + esc(o.state) + "'><td>" + esc(o.id) + "</td><td>" + esc(o.state) +
    (o.reason ? " (" + esc(o.reason) + ")" : "") + "</td><td>" + fmt(o.since, 1) + "</td><td>" + esc(o.from) +
    "</td><td>" + esc(o.to) + "</td><td>" + esc(o.robots.join(" ")) + "</td></tr>";
  document.getElementById("orders").innerHTML = rows;
}

async function control(req) {
  await fetch("/control", { method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(req) });
}
document.getElementById("play").onclick = () => control({ playing: !(state && state.playback.playing) });
document.getElementById("speed").onchange = e => control({ speed: parseFloat(e.target.value) });
document.getElementById("seek").onchange = e => {
  const pb = state.playback; control({ seek: pb.start + (pb.end - pb.start) * e.target.value / 1000 });
};

async function poll() {
  try {
    if (!window.viewerFreeze) {
      const st = await (await fetch("/state", { cache: "no-store" })).json();
      state = st;
      if (st.frame && st.seq !== lastSeq) {
        lastSeq = st.seq;
        record(st.frame);
        const drawn = drawFloor(st.frame);
        drawChart(st.frame);
        side(st);
        window.viewer = { t: st.frame.t, seq: st.seq, mode: st.mode, robots: drawn.robots,
                          loads: drawn.loads, hits: drawn.hits, estimates: drawn.estimates,
                          blind: drawn.blind, cargo: drawn.cargo, orders: st.frame.orders || [],
                          history: historyStats() };
      }
    }
  } catch (err) {
    document.getElementById("meta").textContent = "no connection: " + err;
  }
  setTimeout(poll, 100);
}
loadHistory().then(poll);
</script>
</body></html>
"""


def render_page(title: str = "") -> str:
    """The page, with ``title`` (escaped) as its first title."""
    page = _PAGE.replace("__PALETTE__", json.dumps(list(PALETTE)))
    if title:
        page = page.replace("<title>formation view</title>",
                            f"<title>{html.escape(title)}</title>", 1)
    return page
