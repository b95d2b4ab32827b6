// hng operator station: the page. Vanilla JS, no build step. It draws the latest frame of
// each topic the server streams on /ws, and sends orders with POST /api/* (teleop commands,
// sent while a key is held, go on the stream: stop sending and the Interface's deadman stops
// the robot).
"use strict";

const params = new URLSearchParams(location.search);
const token = params.get("token");
const state = { counts: {}, waypoints: [], answers: [], teleop: null };
window.hng = { state, drawn: { path: 0 } };

const $ = (id) => document.getElementById(id);
const mapCanvas = $("map"), mctx = mapCanvas.getContext("2d");
const camCanvas = $("camera"), cctx = camCanvas.getContext("2d");

function authHeaders() {
  const h = { "Content-Type": "application/json" };
  if (token) h["Authorization"] = "Bearer " + token;
  return h;
}

async function post(path, body) {
  const r = await fetch(path, { method: "POST", headers: authHeaders(), body: JSON.stringify(body) });
  let j = null;
  try { j = await r.json(); } catch (e) { j = { error: "no JSON answer" }; }
  return { status: r.status, body: j };
}

function showAnswer(what, r) {
  let text;
  if (r.status >= 400) text = `${what}: refused by the page server (${r.status}): ${r.body.error}`;
  else if (r.body.answer) {
    const a = r.body.answer;
    text = `${what} (seq ${r.body.seq}): ${a.accepted ? "accepted" : "refused"}${a.reason ? ": " + a.reason : ""}`;
  } else if (r.body.note) text = `${what} (seq ${r.body.seq}): ${r.body.note}`;
  else text = `${what}: ${r.body.done || "sent"}`;
  state.answers.push({ what, status: r.status, body: r.body });
  $("answer").textContent = text;
  $("answer").className = "bar " + (r.status >= 400 || (r.body.answer && !r.body.answer.accepted) ? "bad" : "good");
}

async function order(body, what) { showAnswer(what || body.kind, await post("/api/order", body)); }

// ---- the live stream -------------------------------------------------------------------
let ws = null;
function connect() {
  const url = `${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws${token ? "?token=" + encodeURIComponent(token) : ""}`;
  ws = new WebSocket(url);
  // Images and grids come as binary frames: a 4-byte little-endian length, that many bytes
  // of JSON {"t", "v"} describing them, then the raw bytes (no base64, no big JSON to parse).
  ws.binaryType = "arraybuffer";
  ws.onopen = () => { $("conn").textContent = "live"; $("conn").className = "good"; };
  ws.onclose = () => {
    $("conn").textContent = "disconnected (retrying)"; $("conn").className = "bad";
    setTimeout(connect, 1000);
  };
  ws.onmessage = (ev) => {
    let m, bytes = null;
    if (typeof ev.data === "string") m = JSON.parse(ev.data);
    else {
      const n = new DataView(ev.data).getUint32(0, true);
      m = JSON.parse(utf8.decode(new Uint8Array(ev.data, 4, n)));
      bytes = new Uint8Array(ev.data, 4 + n);
    }
    state.counts[m.t] = (state.counts[m.t] || 0) + 1;
    state[m.t] = m.v;
    // Decoded once per message; drawn at most once per display frame (changed()).
    if (m.t === "map" || m.t === "slam_map") gridImage(m.t, m.v, bytes);
    if (m.t === "image") cameraImage(m.v, bytes);
    if (m.t === "hello") $("prefix").textContent = m.v.prefix;
    if (m.t === "clock") pace.sample(m.v.sim_s);
    if (m.t === "error") { $("answer").textContent = "stream: " + m.v; $("answer").className = "bar bad"; }
    changed(m.t);
  };
}

const utf8 = new TextDecoder();

// ---- map view -----------------------------------------------------------------------------
const grids = {};
function gridImage(name, g, bytes) {
  if (!bytes || bytes.length < g.width * g.height) return;
  const c = document.createElement("canvas");
  c.width = g.width; c.height = g.height;
  const ctx = c.getContext("2d");
  const img = ctx.createImageData(g.width, g.height);
  for (let j = 0; j < g.height; j++) {
    for (let i = 0; i < g.width; i++) {
      const v = bytes[j * g.width + i];
      const o = ((g.height - 1 - j) * g.width + i) * 4;
      let shade;
      if (v === 255) shade = 60; // unknown (-1)
      else shade = 235 - Math.round((Math.min(v, 100) / 100) * 220);
      img.data[o] = img.data[o + 1] = img.data[o + 2] = shade;
      img.data[o + 3] = 255;
    }
  }
  ctx.putImageData(img, 0, 0);
  grids[name] = { canvas: c, info: g };
}

function worldBounds() {
  const g = (grids.map || grids.slam_map || {}).info;
  if (g) return { x0: g.origin.x, y0: g.origin.y, w: g.width * g.resolution, h: g.height * g.resolution };
  return { x0: 0, y0: 0, w: 20, h: 15 };
}

const view = {
  fit() {
    const b = worldBounds(), W = mapCanvas.width, H = mapCanvas.height, pad = 10;
    const s = Math.min((W - 2 * pad) / b.w, (H - 2 * pad) / b.h);
    return { s, b, ox: pad, oy: H - pad };
  },
  toCanvas(x, y) { const f = this.fit(); return [f.ox + (x - f.b.x0) * f.s, f.oy - (y - f.b.y0) * f.s]; },
  toWorld(px, py) { const f = this.fit(); return [f.b.x0 + (px - f.ox) / f.s, f.b.y0 + (f.oy - py) / f.s]; },
  // Page coordinates (for tests and tools) of a world point.
  worldToClient(x, y) {
    const [cx, cy] = this.toCanvas(x, y), r = mapCanvas.getBoundingClientRect();
    return [r.left + cx * r.width / mapCanvas.width, r.top + cy * r.height / mapCanvas.height];
  },
};
window.hng.view = view;

function drawPose(p, color, covariance) {
  const [cx, cy] = view.toCanvas(p.x, p.y), s = view.fit().s;
  if (covariance) {
    // 2-sigma ellipse of the (x, y) covariance.
    const a = covariance[0], b = covariance[1], d = covariance[4];
    const t = (a + d) / 2, q = Math.sqrt(Math.max(((a - d) / 2) ** 2 + b * b, 0));
    const l1 = Math.max(t + q, 0), l2 = Math.max(t - q, 0);
    const ang = Math.atan2(l1 - a, b || 1e-12);
    mctx.save();
    mctx.strokeStyle = color; mctx.globalAlpha = 0.6;
    mctx.beginPath();
    mctx.ellipse(cx, cy, Math.max(2 * Math.sqrt(l1) * s, 1), Math.max(2 * Math.sqrt(l2) * s, 1), -ang, 0, 2 * Math.PI);
    mctx.stroke();
    mctx.restore();
  }
  const r = 0.2 * s;
  mctx.fillStyle = color;
  mctx.beginPath(); mctx.arc(cx, cy, r, 0, 2 * Math.PI); mctx.fill();
  mctx.strokeStyle = "#000"; mctx.beginPath(); mctx.moveTo(cx, cy);
  mctx.lineTo(cx + Math.cos(p.theta) * r * 1.6, cy - Math.sin(p.theta) * r * 1.6); mctx.stroke();
}

function cross(x, y, color, label) {
  const [cx, cy] = view.toCanvas(x, y);
  mctx.strokeStyle = color; mctx.lineWidth = 2;
  mctx.beginPath(); mctx.moveTo(cx - 6, cy - 6); mctx.lineTo(cx + 6, cy + 6);
  mctx.moveTo(cx + 6, cy - 6); mctx.lineTo(cx - 6, cy + 6); mctx.stroke();
  mctx.lineWidth = 1;
  if (label) { mctx.fillStyle = color; mctx.fillText(label, cx + 8, cy - 6); }
}

function drawMap() {
  mctx.fillStyle = "#111"; mctx.fillRect(0, 0, mapCanvas.width, mapCanvas.height);
  const which = $("show-slam").checked && grids.slam_map ? "slam_map" : grids.map ? "map" : "slam_map";
  const g = grids[which];
  if (g) {
    const [x0, y1] = view.toCanvas(g.info.origin.x, g.info.origin.y + g.info.height * g.info.resolution);
    const s = view.fit().s;
    mctx.imageSmoothingEnabled = false;
    mctx.drawImage(g.canvas, x0, y1, g.info.width * g.info.resolution * s, g.info.height * g.info.resolution * s);
  }
  const pose = state.pose && state.pose.pose;
  // Mission goals.
  for (const goal of (state.mission && state.mission.goals) || []) {
    cross(goal.x, goal.y, goal.state === "reached" ? "#6c6" : goal.state === "active" ? "#fc3" : "#888", "" + goal.id);
  }
  if (state.goal && state.goal.id) cross(state.goal.pose.x, state.goal.pose.y, "#fc3", "goal");
  // Waypoints being composed.
  mctx.strokeStyle = "#5af"; mctx.beginPath();
  state.waypoints.forEach((w, i) => { const [cx, cy] = view.toCanvas(w.x, w.y); i ? mctx.lineTo(cx, cy) : mctx.moveTo(cx, cy); });
  mctx.stroke();
  state.waypoints.forEach((w, i) => cross(w.x, w.y, "#5af", "w" + (i + 1)));
  // Planning's whole planned path (planning/path; empty when there is none).
  const path = state.path && state.path.points;
  if (path && path.length > 1) {
    mctx.strokeStyle = "#c6f"; mctx.lineWidth = 2; mctx.beginPath();
    path.forEach(([x, y], i) => { const [cx, cy] = view.toCanvas(x, y); i ? mctx.lineTo(cx, cy) : mctx.moveTo(cx, cy); });
    mctx.stroke(); mctx.lineWidth = 1;
  }
  window.hng.drawn.path = path && path.length > 1 ? path.length : 0;
  // Planning's carrot.
  if (state.waypoint && pose) {
    const w = state.waypoint.pose, [ax, ay] = view.toCanvas(pose.x, pose.y), [bx, by] = view.toCanvas(w.x, w.y);
    mctx.strokeStyle = "#f6f"; mctx.setLineDash([4, 3]); mctx.beginPath(); mctx.moveTo(ax, ay); mctx.lineTo(bx, by); mctx.stroke(); mctx.setLineDash([]);
    mctx.fillStyle = "#f6f"; mctx.beginPath(); mctx.arc(bx, by, 3, 0, 2 * Math.PI); mctx.fill();
  }
  // Laser points, from the pose shown.
  if (state.scan && pose) {
    mctx.fillStyle = "#f33";
    const sc = state.scan;
    sc.ranges.forEach((r, i) => {
      if (r === null) return;
      const a = pose.theta + sc.angle_min + i * sc.angle_increment;
      const [cx, cy] = view.toCanvas(pose.x + r * Math.cos(a), pose.y + r * Math.sin(a));
      mctx.fillRect(cx - 1, cy - 1, 2, 2);
    });
  }
  // Beacons seen (camera frame = robot heading): the trackers' tracks, yellow when a client
  // holds a contract with the tracker (the one the reacher follows), dashed when predicted.
  if (pose) {
    for (const b of seenBeacons()) {
      const a = pose.theta + b.bearing;
      const [cx, cy] = view.toCanvas(pose.x + b.range * Math.cos(a), pose.y + b.range * Math.sin(a));
      const col = b.contracted ? "#fc3" : "#0ff";
      mctx.strokeStyle = col; mctx.setLineDash(b.state === "predicted" ? [2, 2] : []);
      mctx.strokeRect(cx - 5, cy - 5, 10, 10); mctx.setLineDash([]);
      mctx.fillStyle = col; mctx.fillText("b" + b.id, cx + 7, cy + 4);
    }
  }
  if (state.truth) drawPose(state.truth.pose, "rgba(120,255,120,0.5)", null);
  if (pose) drawPose(pose, "#39f", state.pose.covariance);
}

mapCanvas.addEventListener("click", (ev) => {
  const r = mapCanvas.getBoundingClientRect();
  const [x, y] = view.toWorld((ev.clientX - r.left) * mapCanvas.width / r.width, (ev.clientY - r.top) * mapCanvas.height / r.height);
  const p = { x: Math.round(x * 100) / 100, y: Math.round(y * 100) / 100 };
  if (ev.shiftKey) {
    if (state.waypoints.length < 16) state.waypoints.push(p);
  } else {
    state.waypoints = [];
    order({ kind: "goal", points: [p] }, `goal (${p.x}, ${p.y})`);
  }
  updateWaypointButton(); changed("ui");
});
function updateWaypointButton() {
  $("send-wp").textContent = `send waypoints (${state.waypoints.length})`;
  $("send-wp").disabled = state.waypoints.length === 0;
}
$("send-wp").onclick = () => { order({ kind: "waypoints", points: state.waypoints }, "waypoints"); state.waypoints = []; updateWaypointButton(); changed("ui"); };
$("clear-wp").onclick = () => { state.waypoints = []; updateWaypointButton(); changed("ui"); };
$("release").onclick = () => order({ kind: "release" });
$("stop").onclick = () => { teleopRelease(); order({ kind: "stop" }, "STOP"); };
$("show-slam").onchange = () => changed("ui");

// ---- teleop with a deadman: commands flow only while a key or button is held ---------------
const keys = { ArrowUp: [0.4, 0], w: [0.4, 0], ArrowDown: [-0.3, 0], s: [-0.3, 0], ArrowLeft: [0, 1], a: [0, 1], ArrowRight: [0, -1], d: [0, -1] };
const held = new Map();
let teleopTimer = null;
// The simulation's pace (simulated seconds per wall second, from the clock frames): teleop
// commands are sent every 0.1 s of *simulated* time (every 40 ms of wall time at most, 10 ms
// at least), so that the Interface's 0.5 s deadman, which runs on simulated time, never fires
// between two commands of a held key when the simulation runs faster than real time (at 6x,
// 40 ms of wall time would be 0.24 s simulated; at 20x, 0.8 s). Beyond 50x, commands are
// 0.5 s apart in simulated time and the deadman may stop the robot between them.
const pace = {
  factor: 1, last: null,
  sample(simS) {
    const now = performance.now();
    if (this.last && now - this.last.wall > 200) {
      const f = (simS - this.last.sim) / ((now - this.last.wall) / 1000);
      if (f > 0 && isFinite(f)) this.factor = 0.7 * this.factor + 0.3 * f;
      this.last = { wall: now, sim: simS };
    } else if (!this.last) this.last = { wall: now, sim: simS };
  },
  periodMs() { return Math.max(10, Math.min(40, 100 / Math.max(this.factor, 1e-3))); },
};
window.hng.pace = pace;
function teleopTick() {
  teleopSend();
  if (held.size > 0) teleopTimer = setTimeout(teleopTick, pace.periodMs());
}
function teleopCommand() {
  let v = 0, w = 0;
  for (const [dv, dw] of held.values()) { v += dv; w += dw; }
  return { linear_x: Math.max(-0.6, Math.min(0.6, v)), angular_z: Math.max(-1.5, Math.min(1.5, w)) };
}
function teleopSend() {
  if (held.size === 0 || !ws || ws.readyState !== 1) return;
  const c = teleopCommand();
  state.teleop = c;
  ws.send(JSON.stringify({ teleop: c }));
  $("teleop-state").textContent = `v ${c.linear_x.toFixed(2)} m/s, w ${c.angular_z.toFixed(2)} rad/s`;
}
function teleopPress(id, vw) {
  if (held.size === 0) {
    const inForce = state.order_status && state.order_status.in_force;
    if (inForce !== "teleop") order({ kind: "teleop" }, "teleop");
    held.set(id, vw);
    teleopTick();
    return;
  }
  held.set(id, vw);
  teleopSend();
}
function teleopUp(id) {
  held.delete(id);
  if (held.size === 0) teleopRelease();
}
function teleopRelease() {
  held.clear();
  if (teleopTimer) { clearTimeout(teleopTimer); teleopTimer = null; }
  if (ws && ws.readyState === 1) ws.send(JSON.stringify({ teleop: { linear_x: 0, angular_z: 0 } }));
  state.teleop = null;
  $("teleop-state").textContent = "idle";
}
document.addEventListener("keydown", (ev) => {
  const k = keys[ev.key];
  if (!k || ev.target.tagName === "INPUT") return;
  ev.preventDefault();
  if (!held.has("k" + ev.key)) teleopPress("k" + ev.key, k);
});
document.addEventListener("keyup", (ev) => { if (keys[ev.key]) teleopUp("k" + ev.key); });
window.addEventListener("blur", teleopRelease);
for (const b of document.querySelectorAll("#teleop button")) {
  const vw = [parseFloat(b.dataset.v), parseFloat(b.dataset.w)];
  const id = "b" + b.textContent;
  b.addEventListener("pointerdown", () => teleopPress(id, vw));
  for (const e of ["pointerup", "pointerleave", "pointercancel"]) b.addEventListener(e, () => held.has(id) && teleopUp(id));
}

// ---- camera, beacons, designation -------------------------------------------------------
// The camera's horizontal field of view comes with each image (ImageInfo v2 `hfov`); a camera
// that does not give it (0) cannot be clicked (the "designate N" buttons still work).
function cameraFocal() {
  const hfov = state.image && state.image.hfov;
  return hfov > 0 ? camCanvas.width / 2 / Math.tan(hfov / 2) : null;
}
// The column of a bearing (rad, counter-clockwise from the camera's axis), and back.
function bearingColumn(bearing) { const f = cameraFocal(); return f && camCanvas.width / 2 - f * Math.tan(bearing); }
function columnBearing(u) { const f = cameraFocal(); return f && Math.atan2(camCanvas.width / 2 - u, f); }
let cameraPixels = null;
function cameraImage(im, bytes) {
  if (!bytes || bytes.length < im.step * im.height) return;
  if (camCanvas.width !== im.width) { camCanvas.width = im.width; camCanvas.height = im.height; }
  const img = cctx.createImageData(im.width, im.height);
  const rgb = im.encoding !== "mono8";
  for (let y = 0; y < im.height; y++) {
    for (let x = 0; x < im.width; x++) {
      const o = (y * im.width + x) * 4, i = y * im.step + x * (rgb ? 3 : 1);
      img.data[o] = bytes[i]; img.data[o + 1] = bytes[rgb ? i + 1 : i]; img.data[o + 2] = bytes[rgb ? i + 2 : i]; img.data[o + 3] = 255;
    }
  }
  cameraPixels = img;
}
// The image and, over it, a mark at the column of each beacon tracked.
function drawCamera() {
  if (!cameraPixels) return;
  cctx.putImageData(cameraPixels, 0, 0);
  for (const b of seenBeacons()) {
    const u = bearingColumn(b.bearing);
    if (u == null || u < 0 || u > camCanvas.width) continue;
    const col = b.contracted ? "#fc3" : "#0ff";
    cctx.strokeStyle = col; cctx.lineWidth = 2; cctx.setLineDash(b.state === "predicted" ? [3, 3] : []);
    cctx.strokeRect(u - 8, 6, 16, camCanvas.height - 12); cctx.setLineDash([]); cctx.lineWidth = 1;
    cctx.fillStyle = col; cctx.font = "12px sans-serif"; cctx.fillText("b" + b.id, u + 10, 18);
  }
}
// The beacons seen now: the trackers' tracks (seen or predicted; for each beacon the best of
// the contracted tracker's, else the best quality), and a beacon camera's observations when
// the page reads one (Channels::beacons).
function seenBeacons() {
  const by = new Map();
  for (const t of (state.tracks && state.tracks.tracks) || []) {
    if (t.state === "lost") continue;
    const b = { id: t.beacon_id, bearing: t.bearing, range: t.range, state: t.state, quality: t.quality, tracker: t.tracker, contracted: t.contracted_by.length > 0 };
    const old = by.get(b.id);
    if (!old || (b.contracted && !old.contracted) || (b.contracted === old.contracted && b.quality > old.quality)) by.set(b.id, b);
  }
  if (state.beacons) {
    for (const o of state.beacons.beacons.slice(0, state.beacons.count)) {
      if (!by.has(o.id)) by.set(o.id, { id: o.id, bearing: o.bearing, range: o.range, state: "seen", quality: null, tracker: "camera", contracted: false });
    }
  }
  return [...by.values()].sort((a, b) => a.id - b.id);
}
window.hng.seenBeacons = seenBeacons;
function drawTracks() {
  const list = (state.tracks && state.tracks.tracks) || [];
  setHTML($("tracks"), list.length ? list.map((t) =>
    `<li class="${t.state}">beacon ${t.beacon_id}: ${t.state} by ${t.tracker}` +
    (t.state === "lost" ? "" : `, ${t.range.toFixed(2)} m, ${t.bearing.toFixed(2)} rad`) +
    `, Q ${t.quality.toFixed(2)}` +
    (t.contracted_by.length ? ` <b>(tracker of ${t.contracted_by.join(", ")})</b>` : "") + `</li>`).join("")
    : "<li><em>no beacon tracked</em></li>");
}
function designate(id) {
  post("/api/designate", { beacon_id: id }).then((r) => showAnswer(`designate beacon ${id}`, r));
}
camCanvas.addEventListener("click", (ev) => {
  const r = camCanvas.getBoundingClientRect();
  const u = (ev.clientX - r.left) * camCanvas.width / r.width;
  const bearing = columnBearing(u);
  if (bearing == null) {
    $("answer").textContent = "this camera does not give its field of view: use the designate buttons";
    $("answer").className = "bar bad";
    return;
  }
  let best = null;
  for (const b of seenBeacons()) if (!best || Math.abs(b.bearing - bearing) < Math.abs(best.bearing - bearing)) best = b;
  if (best && Math.abs(best.bearing - bearing) < 0.12) designate(best.id);
  else { $("answer").textContent = `no beacon there (bearing ${bearing.toFixed(2)} rad)`; $("answer").className = "bar bad"; }
});

// ---- panels -----------------------------------------------------------------------------
// The DOM is touched only when a panel's content changed: an unchanged panel costs no
// layout or paint.
const shown = new WeakMap();
function setHTML(el, html) { if (shown.get(el) !== html) { shown.set(el, html); el.innerHTML = html; } }
function setText(el, text) { if (el.textContent !== text) el.textContent = text; }
function fmtBytes(b) { return b == null ? "-" : (b / 1048576).toFixed(1) + "M"; }
function drawModules() {
  const st = state.status; if (!st) return;
  const sup = (st.supervisor && st.supervisor.modules) || [], rm = (st.rm && st.rm.modules) || [];
  const rmBy = Object.fromEntries(rm.map((m) => [m.name, m]));
  const vBy = Object.fromEntries(((state.contracts && state.contracts.modules) || []).map((m) => [m.name, m]));
  const rows = sup.map((m) => {
    const r = rmBy[m.name] || {}, c = vBy[m.name] || {};
    const caps = m.caps ? [m.caps.cpu_quota != null ? `cpu ${(m.caps.cpu_quota * 100).toFixed(0)}%` : "", m.caps.memory_max != null ? `mem ${fmtBytes(m.caps.memory_max)}` : ""].join(" ") : "-";
    return `<tr><td>${m.name}${m.manager ? "*" : ""}</td><td>${m.state}</td><td>${m.pid ?? "-"}</td>` +
      `<td>${r.cpu_percent != null ? r.cpu_percent.toFixed(1) : "-"}</td><td>${fmtBytes(r.rss_bytes)}</td><td>${caps}</td>` +
      `<td>${m.restarts}</td><td>${c.value != null ? c.value.toFixed(2) : "-"}</td>` +
      `<td><button data-op="kill" data-m="${m.name}">kill</button><button data-op="restart" data-m="${m.name}">restart</button></td></tr>`;
  });
  setHTML($("modules").tBodies[0], rows.join(""));
  setText($("stream"), st.stream ? `stream: ${st.stream.clients} client(s), ${st.stream.frames_sent} frames sent, ${st.stream.frames_skipped} skipped (latest wins), ${st.stream.clients_dropped} slow client(s) dropped` : "");
}
$("modules").addEventListener("click", (ev) => {
  const b = ev.target.closest("button"); if (!b) return;
  const body = { op: b.dataset.op, module: b.dataset.m };
  if (b.dataset.op === "kill" && !confirm(`Send SIGKILL to ${b.dataset.m}? (the watchdog restarts it)`)) return;
  post("/api/module", body).then((r) => showAnswer(`${body.op} ${body.module}`, r));
});

// Boxes of an SVG element's text or rect, in the SVG's coordinates.
function box(el) { const b = el.getBBox(); return { x: b.x, y: b.y, w: b.width, h: b.height }; }
function overlap(a, b) { return a.x < b.x + b.w && b.x < a.x + a.w && a.y < b.y + b.h && b.y < a.y + a.h; }
// Moves the edge labels so that no two labels (edge or module) overlap: each label, in turn,
// takes the nearest free place (left or right along its row, then rows above and below) from
// its edge's midpoint; the graph grows taller if it must.
function layoutLabels(svg) {
  const W = svg.clientWidth || 560;
  const placed = [...svg.querySelectorAll("text.node")].map(box);
  placed.push(...[...svg.querySelectorAll("rect.node")].map(box));
  let bottom = Math.max(0, ...placed.map((b) => b.y + b.h));
  for (const t of svg.querySelectorAll("text.edge")) {
    const b0 = box(t), x0 = Number(t.getAttribute("x")), y0 = Number(t.getAttribute("y"));
    const step = b0.h + 1;
    let best = null;
    for (let r = 0; r < 40 && !best; r++) {
      for (const dy of r === 0 ? [0] : [r * step, -r * step]) {
        for (const dx of [0, -b0.w / 2, b0.w / 2, -b0.w, b0.w]) {
          const b = { x: b0.x + dx, y: b0.y + dy, w: b0.w, h: b0.h };
          if (b.x < 0 || b.x + b.w > W || b.y < 0) continue;
          if (!placed.some((p) => overlap(p, b))) { best = [dx, dy, b]; break; }
        }
        if (best) break;
      }
    }
    if (!best) { const b = { x: 2, y: bottom + 2, w: b0.w, h: b0.h }; best = [2 - b0.x, b.y - b0.y, b]; }
    t.setAttribute("x", x0 + best[0]); t.setAttribute("y", y0 + best[1]);
    placed.push(best[2]);
    bottom = Math.max(bottom, best[2].y + best[2].h);
  }
  svg.setAttribute("height", Math.max(Number(svg.getAttribute("height")), bottom + 6));
}

let contractsShown = null;
function drawContracts() {
  const c = state.contracts; if (!c) return;
  const svg = $("contracts");
  const key = JSON.stringify(c) + "@" + svg.clientWidth;
  if (key === contractsShown) return;
  contractsShown = key;
  // Depth of each module: the length of its priority (the root has none).
  const depth = {};
  for (const m of c.modules) depth[m.name] = m.root ? 0 : m.priority === "-" ? null : m.priority.split(".").length;
  const levels = {};
  for (const m of c.modules) { const d = depth[m.name] ?? 5; (levels[d] = levels[d] || []).push(m.name); }
  const pos = {}, keys = Object.keys(levels).map(Number).sort((a, b) => a - b);
  const W = svg.clientWidth || 560, rowH = 46;
  svg.setAttribute("height", keys.length * rowH + 20);
  // A row too crowded for its boxes (76 px each) staggers them on two lines.
  keys.forEach((d, row) => levels[d].sort().forEach((n, i, a) => {
    const stagger = a.length * 80 > W ? (i % 2 ? 10 : -10) : 0;
    pos[n] = [((i + 0.5) * W) / a.length, 28 + row * rowH + stagger];
  }));
  const vBy = Object.fromEntries(c.modules.map((m) => [m.name, m]));
  let out = "";
  const edges = [];
  for (const k of c.contracts) {
    const a = pos[k.client], b = pos[k.provider]; if (!a || !b) continue;
    out += `<line x1="${a[0]}" y1="${a[1]}" x2="${b[0]}" y2="${b[1]}" stroke="#6a7" />`;
    edges.push([(a[0] + b[0]) / 2, (a[1] + b[1]) / 2, `${k.service} ${k.priority} V ${k.value.toFixed(2)}`]);
  }
  edges.forEach(([x, y, t], i) => { out += `<text class="edge" data-i="${i}" x="${x + 3}" y="${y}">${t}</text>`; });
  for (const [n, [x, y]] of Object.entries(pos)) {
    const m = vBy[n];
    out += `<rect class="node" x="${x - 38}" y="${y - 9}" width="76" height="16" rx="3" fill="${m.active ? "#2d5b8a" : "#444"}" />`;
    out += `<text class="node" x="${x}" y="${y + 3}" text-anchor="middle">${n}${m.value != null ? " " + m.value.toFixed(2) : ""}</text>`;
  }
  svg.innerHTML = out;
  layoutLabels(svg);
  // Who commands the wheels: the Robot's clients by priority.
  const holders = c.contracts.filter((k) => k.service === "Robot control").sort((a, b) => a.priority.localeCompare(b.priority, undefined, { numeric: true }));
  $("wheels").textContent = holders.length ? holders.map((k) => `${k.client} ${k.priority}`).join(" > ") : "-";
}

function drawTimeline() {
  const ev = state.events || [];
  setHTML($("timeline"), ev.slice().reverse().map((e) => `<li class="${e.kind}">[${e.sim_s.toFixed(1)} s] ${e.text}</li>`).join(""));
}

let behavioursShown = null;
function drawBehaviours() {
  const b = state.behaviours, el = $("behaviours");
  const items = (b && b.items) || [];
  const key = JSON.stringify(items);
  if (key === behavioursShown) return;
  behavioursShown = key;
  if (!items.length) { el.innerHTML = "<em>none offered</em>"; return; }
  el.innerHTML = "";
  for (const it of items) {
    const btn = document.createElement("button");
    let body = { kind: it.kind }, label = it.kind;
    if (it.kind === "reach_beacon") { body.beacon_id = it.param; label = `reach beacon ${it.param}`; }
    if (it.kind === "follow_wall") { body.side = it.param > 0 ? "left" : "right"; label = `follow wall (${body.side})`; }
    btn.textContent = `${label} (${it.quality.toFixed(2)})`;
    btn.onclick = () => order(body, label);
    el.appendChild(btn);
  }
}

function drawHeader() {
  if (state.clock) setText($("simtime"), state.clock.sim_s.toFixed(1) + " s");
  const os = state.order_status;
  setText($("level"), os && os.active ? `operator: ${os.in_force}` : "autonomy (mission)");
  if (state.odom) setText($("speed"), `v ${state.odom.vx.toFixed(2)} m/s`);
  const list = seenBeacons().map((b) => `<button data-b="${b.id}">designate ${b.id}</button>`).join(" ");
  setHTML($("beacons"), list);
}
$("beacons").addEventListener("click", (ev) => { const b = ev.target.closest("button"); if (b) designate(Number(b.dataset.b)); });

// ---- drawing: only what changed, at most once per display frame ---------------------------
// Messages mark their topic changed and ask for one animation frame; nothing runs between
// messages (no animation loop), and a burst of messages costs one drawing. The panels are
// redrawn at most every 250 ms, and only when their data changed.
const MAP_TOPICS = new Set(["pose", "truth", "scan", "path", "waypoint", "goal", "mission", "tracks", "beacons", "map", "slam_map", "ui"]);
const HEADER_TOPICS = new Set(["clock", "order_status", "odom", "tracks", "beacons"]);
const CAMERA_TOPICS = new Set(["image", "tracks", "beacons"]);
const PANEL_TOPICS = new Set(["status", "contracts", "events", "behaviours", "tracks"]);
let pending = new Set(["ui"]), scheduled = false, panelsDue = true, lastPanels = -1e9, panelTimer = null;
function changed(topic) {
  pending.add(topic);
  if (!scheduled) { scheduled = true; requestAnimationFrame(frame); }
}
function frame(t) {
  scheduled = false;
  const p = pending;
  pending = new Set();
  const any = (set) => { for (const x of p) if (set.has(x)) return true; return false; };
  if (any(MAP_TOPICS)) drawMap();
  if (any(HEADER_TOPICS)) drawHeader();
  if (any(CAMERA_TOPICS)) drawCamera();
  if (any(PANEL_TOPICS)) panelsDue = true;
  if (panelsDue) {
    const wait = 250 - (t - lastPanels);
    if (wait <= 0) {
      panelsDue = false; lastPanels = t;
      drawModules(); drawContracts(); drawTimeline(); drawBehaviours(); drawTracks();
    } else if (!panelTimer) {
      panelTimer = setTimeout(() => { panelTimer = null; changed("panels"); }, wait);
    }
  }
}
connect();
changed("ui");
