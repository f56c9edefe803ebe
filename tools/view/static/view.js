// AIDER live view: draws the snapshots the server sends over one WebSocket (plain canvas, no library).
"use strict";

const HISTORY_S = 10;
const COLORS = { l: "#1f77b4", r: "#ff7f0e", com: "#d62828", poly: "#219ebc", cmd: "#6a4c93" };
const series = { fields: [], columns: {} };  // field -> array of values, in time order
// What the page measured, for tests and `aider-exo bench view`: frame-to-page latency (s), updates,
// the gait states it showed and the range of X_CoM/X_SP it showed.
window.viewStats = { updates: 0, frames: 0, latencies: [], lastNewest: null, lastState: null, states: [], xRatio: null };

const $ = (id) => document.getElementById(id);
// Set an element's text or markup only when it changes: the browser then lays out and paints
// only what changed (the page's CPU at 25 updates a second).
const shown = new Map();
function put(el, value, html = false) {
  if (shown.get(el) === value) return;
  shown.set(el, value);
  if (html) el.innerHTML = value; else el.textContent = value;
}
const fmt = (x, d = 2) => (x === null || x === undefined ? "–" : Number(x).toFixed(d));

function connect() {
  const token = new URLSearchParams(location.search).get("token");
  const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws${token ? "?token=" + encodeURIComponent(token) : ""}`;
  const ws = new WebSocket(url);
  ws.onopen = () => { put($("link"), "connected"); $("link").className = "ok"; };
  ws.onclose = () => {
    put($("link"), "disconnected: reconnecting…"); $("link").className = "bad";
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    const received = Date.now() / 1000;
    const snap = JSON.parse(ev.data);
    update(snap);
    const stats = window.viewStats;
    stats.updates += 1;
    stats.frames = snap.frames;
    // the newest frame's latency, once per frame (an update without a newer frame measures nothing)
    if (snap.newest_ts !== null && snap.newest_ts !== stats.lastNewest) {
      if (stats.lastNewest !== null) stats.latencies.push(received - snap.newest_ts);
      stats.lastNewest = snap.newest_ts;
      if (stats.latencies.length > 5000) stats.latencies.shift();
    }
  };
}

function update(s) {
  put($("title"), s.title || "");
  const stale = $("stale");
  if (s.last_rx_wall === null) { stale.hidden = false; put(stale, "no data yet"); }
  else if (s.stale_s > 1) {
    stale.hidden = false;
    put(stale, `no data since ${new Date(s.last_rx_wall * 1000).toLocaleTimeString()}` + (s.source_ended ? " (the trace ended)" : ""));
  } else stale.hidden = true;
  const g = s.gait;
  put($("gait-state"), g.state);
  if (window.viewStats.lastState !== g.state) {
    window.viewStats.lastState = g.state;
    window.viewStats.states.push(g.state);
  }
  put($("steps"), g.steps);
  put($("cycles"), g.cycles);
  put($("tick"), s.tick === null ? "–" : s.tick);
  put($("bus-time"), `${fmt(s.t, 1)} s`);
  put($("bus-load"), `${fmt(100 * s.bus_load, 1)} %`);
  put($("x-ratio"), s.estimate ? fmt(s.estimate.x_ratio) : "–");
  if (s.estimate && Number.isFinite(s.estimate.x_ratio)) {
    const x = s.estimate.x_ratio, r = window.viewStats.xRatio;
    window.viewStats.xRatio = r === null ? { min: x, max: x } : { min: Math.min(r.min, x), max: Math.max(r.max, x) };
  }
  put($("landed"), g.landed.map((st) => `<li value="${st.step}">${st.leg}: ${fmt(st.length_m, 3)} m at ${fmt(st.t, 1)} s</li>`).join(""), true);
  const st = g.controller_step;
  put($("commanded"), st && st.commanded_m !== null ? `${fmt(st.commanded_m, 3)} m (step ${st.index})` : "–");
  put($("placed"), st && st.placed_m !== null ? `${fmt(st.placed_m, 3)} m` : "–");
  put($("step-cost"), st && st.cost_n !== null ? `${fmt(st.cost_n, 1)} N` : "–");
  put($("policy"), st ? st.policy : "–");
  drawLearning(s.learning);
  addSamples(s.kind === "full", s.series);
  drawSagittal(s.estimate);
  drawTop(s.estimate);
  drawPlots();
  drawNodes(s);
}

function addSamples(full, incoming) {
  if (full || series.fields.length === 0) {
    series.fields = incoming.fields;
    series.columns = Object.fromEntries(incoming.fields.map((f) => [f, []]));
  }
  const cols = incoming.fields.map((f) => series.columns[f]);
  const n = series.columns.n;
  for (const row of incoming.samples) {
    if (n.length && row[0] <= n[n.length - 1]) continue;  // seen already
    row.forEach((v, i) => cols[i].push(v));
  }
  const t = series.columns.t;
  let drop = 0;
  while (drop < t.length && t[drop] < t[t.length - 1] - HISTORY_S) drop++;
  if (drop) for (const f of series.fields) series.columns[f].splice(0, drop);
}

// -- sketches ----------------------------------------------------------------------------------

function frame(canvas, xmin, xmax, ymin, ymax) {
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const scale = Math.min(canvas.width / (xmax - xmin), canvas.height / (ymax - ymin));
  const ox = (canvas.width - scale * (xmax - xmin)) / 2, oy = (canvas.height - scale * (ymax - ymin)) / 2;
  const X = (x) => ox + (x - xmin) * scale, Y = (y) => canvas.height - oy - (y - ymin) * scale;
  return { ctx, X, Y, scale };
}

function dot(ctx, x, y, r, color, filled) {
  ctx.beginPath(); ctx.arc(x, y, r, 0, 2 * Math.PI);
  ctx.strokeStyle = color; ctx.fillStyle = color; ctx.lineWidth = 2;
  filled ? ctx.fill() : ctx.stroke();
}

function drawSagittal(e) {
  const canvas = $("sagittal");
  if (!e) { canvas.getContext("2d").clearRect(0, 0, canvas.width, canvas.height); return; }
  const xs = [...e.ankles.map((a) => a[0]), ...e.tips.map((p) => p[0]), e.com[0]];
  const mid = (Math.min(...xs) + Math.max(...xs)) / 2;
  const f = frame(canvas, mid - 0.75, mid + 0.75, -0.05, 1.15);
  const { ctx, X, Y } = f;
  const floor = e.floor_z;
  const hip = [0, -floor];  // the heading frame's origin: midway between the hip joints
  ctx.strokeStyle = "#888"; ctx.lineWidth = 1;
  ctx.beginPath(); ctx.moveTo(0, Y(0)); ctx.lineTo(canvas.width, Y(0)); ctx.stroke();
  // the support's fore-aft extent on the floor, and the CoM's place in it
  const sx = e.support.map((p) => p[0]);
  if (sx.length) {
    ctx.fillStyle = "#8ecae688";
    ctx.fillRect(X(Math.min(...sx)), Y(0) - 4, X(Math.max(...sx)) - X(Math.min(...sx)), 8);
  }
  ["l", "r"].forEach((side, i) => {
    const a = e.ankles[i], tip = e.tips[i];
    ctx.strokeStyle = COLORS[side]; ctx.lineWidth = 1.5;
    ctx.beginPath(); ctx.moveTo(X(hip[0]), Y(hip[1])); ctx.lineTo(X(a[0]), Y(a[2] - floor)); ctx.stroke();
    ctx.lineWidth = 3;
    ctx.beginPath(); ctx.moveTo(X(a[0]) - 0.05 * f.scale, Y(a[2] - floor) + 6); ctx.lineTo(X(a[0]) + 0.15 * f.scale, Y(a[2] - floor) + 6); ctx.stroke();
    dot(ctx, X(a[0]), Y(a[2] - floor), 4, COLORS[side], e.feet_loaded[i]);
    dot(ctx, X(tip[0]), Y(tip[2] - floor), 4, COLORS[side], e.sticks_loaded[i]);
  });
  for (const [key, dash] of [["commanded", [6, 4]], ["measured", []]]) {
    const path = e.paths[key];
    if (!path.length) continue;
    ctx.setLineDash(dash); ctx.strokeStyle = COLORS.cmd; ctx.lineWidth = 2;
    ctx.beginPath();
    path.forEach(([x, z], k) => (k ? ctx.lineTo(X(x), Y(z)) : ctx.moveTo(X(x), Y(z))));
    ctx.stroke(); ctx.setLineDash([]);
  }
  const cx = X(e.com[0]), cz = Y(e.com[2] - floor);
  ctx.strokeStyle = COLORS.com; ctx.setLineDash([3, 3]); ctx.lineWidth = 1;
  ctx.beginPath(); ctx.moveTo(cx, cz); ctx.lineTo(cx, Y(0)); ctx.stroke(); ctx.setLineDash([]);
  dot(ctx, cx, cz, 7, COLORS.com, true);
  canvas.dataset.comX = e.com[0];
}

function drawTop(e) {
  const canvas = $("topdown");
  if (!e) { canvas.getContext("2d").clearRect(0, 0, canvas.width, canvas.height); return; }
  const xs = [...e.ankles.map((a) => a[0]), ...e.tips.map((p) => p[0]), e.com[0]];
  const mid = (Math.min(...xs) + Math.max(...xs)) / 2;
  // x forward to the right, y (left) up
  const f = frame(canvas, mid - 0.9, mid + 0.9, -0.45, 0.45);
  const { ctx, X, Y } = f;
  if (e.support.length) {
    ctx.beginPath();
    e.support.forEach(([x, y], k) => (k ? ctx.lineTo(X(x), Y(y)) : ctx.moveTo(X(x), Y(y))));
    ctx.closePath(); ctx.fillStyle = "#8ecae666"; ctx.fill(); ctx.strokeStyle = COLORS.poly; ctx.lineWidth = 1.5; ctx.stroke();
  }
  ["l", "r"].forEach((side, i) => {
    const a = e.ankles[i], tip = e.tips[i];
    ctx.strokeStyle = COLORS[side]; ctx.lineWidth = 2;
    ctx.strokeRect(X(a[0] - 0.05), Y(a[1] + 0.05), 0.2 * f.scale, 0.1 * f.scale);
    dot(ctx, X(a[0]), Y(a[1]), 4, COLORS[side], e.feet_loaded[i]);
    dot(ctx, X(tip[0]), Y(tip[1]), 5, COLORS[side], e.sticks_loaded[i]);
  });
  dot(ctx, X(e.com[0]), Y(e.com[1]), 7, COLORS.com, true);
  canvas.dataset.comX = e.com[0];
  canvas.dataset.comY = e.com[1];
  canvas.dataset.comPx = Math.round(X(e.com[0]));  // where the marker is drawn, across the canvas
}

// -- rolling plots -----------------------------------------------------------------------------

function plot(canvas, panels) {
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const t = series.columns.t || [];
  canvas.dataset.points = t.length;
  if (t.length < 2) return;
  const t1 = t[t.length - 1], t0 = t1 - HISTORY_S;
  const h = canvas.height / panels.length, left = 48, w = canvas.width - left - 130;
  panels.forEach((panel, p) => {
    const top = p * h + 6, height = h - 16;
    let lo = Infinity, hi = -Infinity;
    for (const line of panel.lines) for (const v of series.columns[line.field]) if (v !== null) { lo = Math.min(lo, v); hi = Math.max(hi, v); }
    if (!isFinite(lo)) { lo = 0; hi = 1; }
    if (panel.zero) lo = Math.min(lo, 0);
    if (hi - lo < 1e-6) hi = lo + 1;
    const X = (x) => left + ((x - t0) / HISTORY_S) * w, Y = (y) => top + height - ((y - lo) / (hi - lo)) * height;
    ctx.fillStyle = "#5a6375"; ctx.font = "11px system-ui";
    ctx.fillText(fmt(hi, 1), 2, top + 9); ctx.fillText(fmt(lo, 1), 2, top + height);
    ctx.strokeStyle = "#e3e6eb"; ctx.lineWidth = 1; ctx.strokeRect(left, top, w, height);
    panel.lines.forEach((line, k) => {
      const ys = series.columns[line.field];
      ctx.strokeStyle = line.color; ctx.lineWidth = 1.5; ctx.setLineDash(line.dash || []);
      ctx.beginPath();
      let pen = false;
      for (let i = 0; i < t.length; i++) {
        if (ys[i] === null) { pen = false; continue; }
        pen ? ctx.lineTo(X(t[i]), Y(ys[i])) : ctx.moveTo(X(t[i]), Y(ys[i]));
        pen = true;
      }
      ctx.stroke(); ctx.setLineDash([]);
      ctx.fillStyle = line.color; ctx.fillText(line.label, left + w + 8, top + 12 + 13 * k);
    });
    ctx.fillStyle = "#1d2330"; ctx.fillText(panel.title, left + 4, top + 12);
  });
}

function drawPlots() {
  plot($("plot-forces"), [{ title: "stick force N", zero: true, lines: [
    { field: "stick_force_l", color: COLORS.l, label: "left stick" }, { field: "stick_force_r", color: COLORS.r, label: "right stick" }] }]);
  plot($("plot-plantar"), [{ title: "plantar load N", zero: true, lines: [
    { field: "heel_l", color: COLORS.l, label: "left heel" }, { field: "toe_l", color: COLORS.l, dash: [4, 3], label: "left toe" },
    { field: "heel_r", color: COLORS.r, label: "right heel" }, { field: "toe_r", color: COLORS.r, dash: [4, 3], label: "right toe" }] }]);
  plot($("plot-joints"), [
    { title: "hips rad", lines: [
      { field: "q_lh", color: COLORS.l, label: "left measured" }, { field: "cmd_lh", color: COLORS.l, dash: [5, 3], label: "left commanded" },
      { field: "q_rh", color: COLORS.r, label: "right measured" }, { field: "cmd_rh", color: COLORS.r, dash: [5, 3], label: "right commanded" }] },
    { title: "knees rad", lines: [
      { field: "q_lk", color: COLORS.l, label: "left measured" }, { field: "cmd_lk", color: COLORS.l, dash: [5, 3], label: "left commanded" },
      { field: "q_rk", color: COLORS.r, label: "right measured" }, { field: "cmd_rk", color: COLORS.r, dash: [5, 3], label: "right commanded" }] }]);
}

function drawLearning(l) {
  put($("theta"), l ? `${fmt(l.alpha, 2)}, ${fmt(l.xhat_com, 3)}` : "–");
  put($("update"), l ? l.update : "–");
  put($("rollout"), l ? l.rollout : "–");
  put($("cycle"), l ? l.cycle : "–");
  const canvas = $("plot-costs");
  const key = JSON.stringify(l ? l.costs : null);
  if (canvas.dataset.drawn === key) return;  // redrawn only when a cost comes
  canvas.dataset.drawn = key;
  const ctx = canvas.getContext("2d");
  ctx.clearRect(0, 0, canvas.width, canvas.height);
  const costs = l ? l.costs : [];
  canvas.dataset.points = costs.length;
  ctx.fillStyle = "#5a6375"; ctx.font = "11px system-ui";
  if (!costs.length) { ctx.fillText("gait-cycle costs appear here while learning", 8, 16); return; }
  const hi = Math.max(...costs.map((c) => c.cost_n)) || 1, w = canvas.width / 60;
  costs.forEach((c, i) => {
    const h = (c.cost_n / hi) * (canvas.height - 16);
    ctx.fillStyle = c.rollout % 2 ? "#219ebc" : "#8ecae6";
    ctx.fillRect(i * w, canvas.height - h, w - 1, h);
  });
  ctx.fillStyle = "#1d2330"; ctx.fillText(`gait-cycle cost, last ${costs.length} (max ${fmt(hi, 1)} N)`, 4, 12);
}

// -- health ------------------------------------------------------------------------------------

function drawNodes(s) {
  put($("nodes").tBodies[0], Object.entries(s.nodes).map(([name, n]) => {
    const cls = n.drive_state === "FAULT" || n.error_code !== "NONE" ? "fault"
      : (n.nmt !== "OPERATIONAL" || (n.heartbeat_age_s !== null && n.heartbeat_age_s > 0.3)) ? "warn" : "";
    return `<tr class="${cls}" data-node="${name}"><td>${name}</td><td>${n.nmt}</td><td>${fmt(n.heartbeat_age_s)} s</td>` +
      `<td>${fmt(n.supply_v, 1)} V</td><td>${n.drive_state}</td><td class="error">${n.error_code}</td><td>${fmt(n.status_age_s)} s</td></tr>`;
  }).join(""), true);
  put($("emcy"), s.emcy.map((e) => `<li>${fmt(e.t, 2)} s ${e.node}: ${e.code} (register ${e.register}, detail ${e.detail})</li>`).join(""), true);
  const r = s.receiver;
  const rows = [["accepted", r.accepted], ["lost (counter gaps)", r.lost],
    ...Object.entries(r.rejected_by_reason).map(([k, v]) => [`rejected: ${k}`, v])];
  put($("receiver"), rows.map(([k, v]) => `<tr><th>${k}</th><td>${v}</td></tr>`).join(""), true);
}

connect();
