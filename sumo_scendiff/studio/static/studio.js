// The scenario studio's page: the network on a canvas, a window, tokens, generation, keeping.
// Plain JS, no build step, no network access beyond its own server (docs/studio.md).
"use strict";

const CELL_M = 250;        // lanes are grouped into cells of this size: a redraw draws only the cells in view
const LOD_PX_PER_M = 1.5;  // below this zoom only car lanes are drawn (a redraw of a whole city in < 50 ms)
const WINDOW_M = 100;      // the generation window's side (run's window)
const DENSITY_COLOURS = ["#4575b4", "#91bfdb", "#e0f3f8", "#fee090", "#fc8d59", "#d73027"];
const STATUS_COLOURS = { placed: "#2b6cb0", misplaced: "#dd8a00", refused: "#c00", existing: "#718096", dropped: "#c00" };
const LANE_STYLE = {
  car: ["#5a5a5a", 3.0], internal: ["#6b6b6b", 3.0], walk: ["#d6d2c4", 1.8], other: ["#b9b9a8", 2.0],
};

const S = {                 // the page's state, also read by the browser test
  net: null, cells: [], view: { s: 1, ox: 0, oy: 0 }, mode: "pan", win: null,
  tokens: [], sel: -1, pMask: null, result: null, scene: 0, fill: null,
  drawMs: 0, draws: 0, drawn: { cells: 0, full: 0, boxes: 0, tokens: 0 }, busy: false, kept: null,
};
window.studio = S;

const $ = (id) => document.getElementById(id);
const canvas = $("canvas");
const ctx = canvas.getContext("2d");

async function api(path, body) {
  const r = await fetch(path, body === undefined ? {} : {
    method: "POST", headers: { "Content-Type": "application/json" }, body: JSON.stringify(body) });
  const doc = await r.json();
  if (!r.ok) throw new Error(doc.error || `${path}: HTTP ${r.status}`);
  return doc;
}

// ---- the network, cached as Path2D per cell and style -----------------------------------------
function laneStyle(lane) {
  if (S.fill && lane.kind === "car") {
    const d = S.fill.edges[lane.edge] || 0;
    const k = Math.min(DENSITY_COLOURS.length - 1, Math.floor(d / Math.max(S.fill.max, 1e-9) * DENSITY_COLOURS.length));
    return "d" + k;
  }
  return lane.kind;
}

function buildCells() {
  const cells = new Map();
  const cellOf = (x, y) => {
    const key = Math.floor(x / CELL_M) + "," + Math.floor(y / CELL_M);
    if (!cells.has(key)) cells.set(key, { box: [Infinity, Infinity, -Infinity, -Infinity], paths: {}, junctions: new Path2D() });
    return cells.get(key);
  };
  const grow = (c, pts) => {
    for (let i = 0; i < pts.length; i += 2) {
      c.box[0] = Math.min(c.box[0], pts[i]); c.box[1] = Math.min(c.box[1], pts[i + 1]);
      c.box[2] = Math.max(c.box[2], pts[i]); c.box[3] = Math.max(c.box[3], pts[i + 1]);
    }
  };
  for (const j of S.net.junctions) {
    const p = j.ring, c = cellOf(p[0], p[1]);
    c.junctions.moveTo(p[0], p[1]);
    for (let i = 2; i < p.length; i += 2) c.junctions.lineTo(p[i], p[i + 1]);
    c.junctions.closePath();
    grow(c, p);
  }
  for (const ln of S.net.lanes) {
    const p = ln.shape, m = (p.length >> 2) << 1, c = cellOf(p[m], p[m + 1]);
    const st = laneStyle(ln);
    const path = c.paths[st] || (c.paths[st] = new Path2D());
    path.moveTo(p[0], p[1]);
    for (let i = 2; i < p.length; i += 2) path.lineTo(p[i], p[i + 1]);
    grow(c, p);
  }
  S.cells = [...cells.values()];
}

function styleOf(st) {
  if (st[0] === "d") return [DENSITY_COLOURS[+st.slice(1)], 3.0];
  return LANE_STYLE[st];
}

// ---- view ---------------------------------------------------------------------------------------
const toWorld = (sx, sy) => [(sx - S.view.ox) / S.view.s, (S.view.oy - sy) / S.view.s];
const toScreen = (x, y) => [S.view.ox + x * S.view.s, S.view.oy - y * S.view.s];

function fit(box, w, h, margin = 0.05) {
  const [x0, y0, x1, y1] = box;
  const s = Math.min(w / (x1 - x0), h / (y1 - y0)) * (1 - 2 * margin);
  return { s, ox: w / 2 - s * (x0 + x1) / 2, oy: h / 2 + s * (y0 + y1) / 2 };
}

// Lanes narrower than this many device pixels are drawn one device pixel wide: Chromium's software rasteriser
// strokes a hairline about thirty times faster than an antialiased line of a pixel or two (docs/studio.md, Speed)
const HAIRLINE_PX = 2;
const STYLES_NEAR = ["walk", "other", "internal", "car", "d0", "d1", "d2", "d3", "d4", "d5"];
const STYLES_FAR = ["internal", "car", "d0", "d1", "d2", "d3", "d4", "d5"];

// The network into context c seen through view, for a w x h (CSS px) canvas, only what lies in part
// [x0, y0, x1, y1] of it (default: all of it); returns the number of cells drawn.
function drawNetwork(c, view, w, h, dpr, part = null) {
  const [sx0, sy0, sx1, sy1] = part || [0, 0, w, h];
  const pad = 2 + 2 / view.s;   // a cell's box holds its lanes' centre lines: half a lane and a pixel more
  const wx0 = (sx0 - view.ox) / view.s - pad, wy1 = (view.oy - sy0) / view.s + pad;
  const wx1 = (sx1 - view.ox) / view.s + pad, wy0 = (view.oy - sy1) / view.s - pad;
  const inView = (cl) => cl.box[2] >= wx0 && cl.box[0] <= wx1 && cl.box[3] >= wy0 && cl.box[1] <= wy1;
  c.setTransform(dpr * view.s, 0, 0, -dpr * view.s, dpr * view.ox, dpr * view.oy);
  c.lineCap = "butt"; c.lineJoin = "bevel";   // round joins cost a third more on a whole city
  const px = 1 / view.s, hair = 1 / (view.s * dpr), far = view.s < LOD_PX_PER_M;
  let n = 0;
  c.fillStyle = "#8f8f8f";
  for (const cl of S.cells) if (inView(cl)) { c.fill(cl.junctions); n++; }
  // zoomed out, where a lane is a few pixels wide, sidewalks and other non-car lanes are left out and the
  // lanes inside junctions (drawn over by the junction's own outline) are hairlines
  for (const st of far ? STYLES_FAR : STYLES_NEAR) {
    const [colour, width] = styleOf(st);
    c.strokeStyle = colour;
    c.lineWidth = (far && st === "internal") || width * view.s * dpr < HAIRLINE_PX ? hair : width;
    for (const cl of S.cells) if (cl.paths[st] && inView(cl)) c.stroke(cl.paths[st]);
  }
  if (view.s > 0.8) {          // lights only where they can be seen
    c.fillStyle = "#d33";
    const r = Math.max(0.9, 2 * px);
    c.beginPath();
    for (const l of S.net.lights) {
      if (l.x < wx0 || l.x > wx1 || l.y < wy0 || l.y > wy1) continue;
      c.moveTo(l.x + r, l.y); c.arc(l.x, l.y, r, 0, 2 * Math.PI);
    }
    c.fill();
  }
  return n;
}

// A scene's shapes in network coordinates, built once per scene: a frame only fills and strokes them.
const sceneShapes = new WeakMap();
function addBox(p, a) {
  const c = Math.cos(a.heading), s = Math.sin(a.heading), hl = a.length / 2, hw = a.width / 2;
  p.moveTo(a.x + hl * c - hw * s, a.y + hl * s + hw * c);
  p.lineTo(a.x + hl * c + hw * s, a.y + hl * s - hw * c);
  p.lineTo(a.x - hl * c + hw * s, a.y - hl * s - hw * c);
  p.lineTo(a.x - hl * c - hw * s, a.y - hl * s + hw * c);
  p.closePath();
}

function shapesOf(scene) {
  let sh = sceneShapes.get(scene);
  if (sh) return sh;
  sh = { paths: new Path2D(), fills: new Map(), good: new Path2D(), bad: new Path2D(), tokens: new Path2D() };
  for (const a of scene.agents) {
    const bad = a.status === "refused" || a.status === "dropped";
    if (a.path.length > 1) {
      sh.paths.moveTo(a.path[0][0], a.path[0][1]);
      for (let i = 1; i < a.path.length; i++) sh.paths.lineTo(a.path[i][0], a.path[i][1]);
    }
    const colour = bad ? "#c0000040" : STATUS_COLOURS[a.status] || "#2b6cb0";
    if (!sh.fills.has(colour)) sh.fills.set(colour, new Path2D());
    addBox(sh.fills.get(colour), a);
    addBox(bad ? sh.bad : sh.good, a);
    if (bad) {                 // refused or dropped: a cross over the box
      const r = a.length / 2;
      sh.bad.moveTo(a.x - r, a.y - r); sh.bad.lineTo(a.x + r, a.y + r);
      sh.bad.moveTo(a.x - r, a.y + r); sh.bad.lineTo(a.x + r, a.y - r);
    }
    if (a.source === "user" && a.token !== null && a.token !== undefined) {   // the vehicle of a token
      const r = a.length / 2 + 1.5;
      sh.tokens.moveTo(a.x + r, a.y); sh.tokens.arc(a.x, a.y, r, 0, 2 * Math.PI);
    }
  }
  sceneShapes.set(scene, sh);
  return sh;
}

function drawScene(c, scene, px) {
  const sh = shapesOf(scene);
  c.strokeStyle = "#1a4f8acc"; c.lineWidth = Math.max(0.35, 1.5 * px); c.stroke(sh.paths);
  for (const [colour, p] of sh.fills) { c.fillStyle = colour; c.fill(p); }
  c.strokeStyle = "#fff"; c.lineWidth = 0.25; c.stroke(sh.good);
  c.strokeStyle = "#c00"; c.lineWidth = 0.6; c.stroke(sh.bad);
  c.strokeStyle = "#0a0"; c.lineWidth = Math.max(0.5, 2 * px); c.stroke(sh.tokens);
  return scene.agents.length;
}

function windowCorners(win) {
  const c = Math.cos(win.yaw), s = Math.sin(win.yaw), h = WINDOW_M / 2;
  return [[h, h], [h, -h], [-h, -h], [-h, h]].map(([u, v]) => [win.cx + u * c - v * s, win.cy + u * s + v * c]);
}
const handlePoint = (win) => [win.cx + 0.6 * WINDOW_M * Math.cos(win.yaw), win.cy + 0.6 * WINDOW_M * Math.sin(win.yaw)];

function drawWindow(c, px) {
  if (!S.win) return;
  const q = windowCorners(S.win);
  c.strokeStyle = "#2b6cb0"; c.lineWidth = 2 * px; c.setLineDash([6 * px, 4 * px]);
  c.beginPath(); c.moveTo(...q[0]); for (const p of q.slice(1)) c.lineTo(...p); c.closePath(); c.stroke();
  c.setLineDash([]);
  const [hx, hy] = handlePoint(S.win);
  c.beginPath(); c.moveTo(S.win.cx, S.win.cy); c.lineTo(hx, hy); c.stroke();
  c.fillStyle = "#2b6cb0"; c.beginPath(); c.arc(hx, hy, 6 * px, 0, 2 * Math.PI); c.fill();
}

function drawTokens(c, px) {
  S.tokens.forEach((t, i) => {
    const r = Math.max(2.5, 7 * px);
    c.lineWidth = 2 * px; c.strokeStyle = i === S.sel ? "#e07b00" : "#0a0"; c.fillStyle = "#ffffffaa";
    c.beginPath(); c.arc(t.x, t.y, r, 0, 2 * Math.PI);
    if (!S.result) c.fill();     // over a generated scene the vehicle under the token stays visible
    c.stroke();
    c.beginPath(); c.moveTo(t.x, t.y); c.lineTo(t.x + 2 * r * Math.cos(t.heading), t.y + 2 * r * Math.sin(t.heading)); c.stroke();
    c.save(); c.translate(t.x, t.y); c.scale(px, -px);
    c.fillStyle = "#063"; c.font = "bold 11px sans-serif"; c.fillText(String(i), 9, -9); c.restore();
  });
  return S.tokens.length;
}

function draw() {
  const t0 = performance.now();
  const dpr = window.devicePixelRatio || 1, w = canvas.clientWidth, h = canvas.clientHeight;
  if (canvas.width !== Math.round(w * dpr) || canvas.height !== Math.round(h * dpr)) {
    canvas.width = Math.round(w * dpr); canvas.height = Math.round(h * dpr);
  }
  ctx.setTransform(1, 0, 0, 1, 0, 0); ctx.clearRect(0, 0, canvas.width, canvas.height);
  if (!S.net) return;
  const px = 1 / S.view.s;
  drawLayer(dpr);
  ctx.setTransform(dpr * S.view.s, 0, 0, -dpr * S.view.s, dpr * S.view.ox, dpr * S.view.oy);
  const scene = S.result && S.result.scenes[S.scene];
  S.drawn.boxes = scene ? drawScene(ctx, scene, px) : 0;
  drawWindow(ctx, px);
  S.drawn.tokens = drawTokens(ctx, px);
  S.drawMs = performance.now() - t0; S.draws++;
}

// The network is drawn into a layer the size of the view and kept. A pan shifts the layer by whole device
// pixels and draws only the strips that come into view; a zoom scales the layer, and once the zoom has
// rested for ZOOM_REST_MS the scaled picture is drawn sharp again one band of BAND_PX rows a frame (the
// middle first). Only a new network look, a resize or a jump draws the whole view in one frame.
const ZOOM_REST_MS = 200, BAND_PX = 256;
const layer = { front: document.createElement("canvas"), back: document.createElement("canvas"),
                s: 0, ox: 0, oy: 0, dpr: 0, valid: false, rest: null, bands: [] };

function dropLayer() { layer.valid = false; }   // the network looks different (a fill.json)

function drawLayer(dpr) {
  const v = S.view, W = canvas.width, H = canvas.height, L = layer;
  if (!L.valid || L.dpr !== dpr || L.front.width !== W || L.front.height !== H) fullLayer(dpr);
  else if (L.s !== v.s) {      // zooming: the layer scaled until the zoom rests
    const k = v.s / L.s;
    ctx.setTransform(1, 0, 0, 1, 0, 0);
    ctx.drawImage(L.front, (v.ox - k * L.ox) * dpr, (v.oy - k * L.oy) * dpr, W * k, H * k);
    clearTimeout(L.rest);
    L.rest = setTimeout(() => { if (L.s !== S.view.s) { restLayer(dpr); redraw(); } }, ZOOM_REST_MS);
    return;
  } else {
    const dx = Math.round((v.ox - L.ox) * dpr), dy = Math.round((v.oy - L.oy) * dpr);
    if (Math.abs(dx) >= W || Math.abs(dy) >= H) fullLayer(dpr);
    else if (dx || dy) shiftLayer(dx, dy, dpr);
  }
  if (L.bands.length) { sharpenBand(dpr); if (L.bands.length) redraw(); }
  ctx.setTransform(1, 0, 0, 1, 0, 0);
  ctx.drawImage(L.front, 0, 0);
}

// A zoom has rested: the scaled picture becomes the layer at the new scale, every band of it to be drawn sharp.
function restLayer(dpr) {
  const v = S.view, L = layer, W = L.front.width, H = L.front.height, k = v.s / L.s, c = L.back.getContext("2d");
  c.setTransform(1, 0, 0, 1, 0, 0); c.clearRect(0, 0, W, H);
  c.drawImage(L.front, (v.ox - k * L.ox) * dpr, (v.oy - k * L.oy) * dpr, W * k, H * k);
  const shown = L.back; L.back = L.front; L.front = shown;
  Object.assign(L, { s: v.s, ox: v.ox, oy: v.oy });
  L.bands.length = 0;
  for (let y = 0; y < H; y += BAND_PX) L.bands.push([y, Math.min(H, y + BAND_PX)]);
  L.bands.sort((a, b) => Math.abs(a[0] + a[1] - H) - Math.abs(b[0] + b[1] - H));
}

function sharpenBand(dpr) {
  const L = layer, [y0, y1] = L.bands.shift(), W = L.front.width, c = L.front.getContext("2d");
  c.setTransform(1, 0, 0, 1, 0, 0); c.clearRect(0, y0, W, y1 - y0);
  drawStrip(c, 0, y0, W, y1 - y0, dpr);
}

function fullLayer(dpr) {
  const v = S.view, L = layer, W = canvas.width, H = canvas.height;
  if (L.front.width !== W || L.front.height !== H) { L.front.width = L.back.width = W; L.front.height = L.back.height = H; }
  const c = L.front.getContext("2d");
  c.setTransform(1, 0, 0, 1, 0, 0); c.clearRect(0, 0, W, H);
  Object.assign(L, { s: v.s, ox: v.ox, oy: v.oy, dpr, valid: true });
  L.bands.length = 0;
  S.drawn.cells = drawNetwork(c, v, W / dpr, H / dpr, dpr);
  S.drawn.full++;
}

// The layer moved by (dx, dy) device pixels: copied over, and the strips uncovered drawn, each clipped to
// itself (the strips do not overlap: an edge drawn twice would be darker).
function shiftLayer(dx, dy, dpr) {
  const L = layer, W = L.front.width, H = L.front.height, c = L.back.getContext("2d");
  L.ox += dx / dpr; L.oy += dy / dpr;      // the layer's own origin: whole pixels from where it was drawn
  c.setTransform(1, 0, 0, 1, 0, 0); c.clearRect(0, 0, W, H);
  c.drawImage(L.front, dx, dy);
  if (dy && L.bands.length) {   // rows still to be drawn sharp move with the picture
    for (const b of L.bands) { b[0] = Math.min(H, Math.max(0, b[0] + dy)); b[1] = Math.min(H, Math.max(0, b[1] + dy)); }
    L.bands = L.bands.filter((b) => b[1] > b[0]);
  }
  const x0 = dx > 0 ? 0 : W + dx, y0 = dy > 0 ? 0 : H + dy, ax = Math.abs(dx), ay = Math.abs(dy);
  S.drawn.cells = 0;
  if (dx) drawStrip(c, x0, 0, ax, H, dpr);
  if (dy) drawStrip(c, dx > 0 ? ax : 0, y0, W - ax, ay, dpr);
  const shown = L.back; L.back = L.front; L.front = shown;
}

function drawStrip(c, x, y, w, h, dpr) {
  const L = layer;
  c.save(); c.beginPath(); c.rect(x, y, w, h); c.clip();
  S.drawn.cells += drawNetwork(c, L, L.front.width / dpr, L.front.height / dpr, dpr,
                               [x / dpr, y / dpr, (x + w) / dpr, (y + h) / dpr]);
  c.restore();
}

let pending = false;
function redraw() { if (!pending) { pending = true; requestAnimationFrame(() => { pending = false; draw(); }); } }

// ---- tokens ---------------------------------------------------------------------------------------
const FEATURES = ["vclass", "vtype", "length", "width", "speed", "final_speed", "manoeuvre", "heading_to_final"];

function tokenBody() {
  return { p_mask: S.pMask, agents: S.tokens.map((t) => {
    const a = { edge: t.edge, lane: t.index, pos: t.pos };
    for (const k of FEATURES) if (t.f[k] !== undefined && t.f[k] !== "") a[k] = t.f[k];
    return a;
  }) };
}

let previewTimer = null;
function preview() {
  clearTimeout(previewTimer);
  previewTimer = setTimeout(async () => {
    try { $("toml").textContent = (await api("/api/tokens", tokenBody())).toml; $("token-error").textContent = ""; }
    catch (e) { $("token-error").textContent = e.message; }
  }, 120);
}

function lanePoint(laneId, pos) {
  const ln = S.net.lanes.find((l) => l.id === laneId), p = ln.shape;
  let left = Math.max(0, Math.min(pos, ln.length));
  for (let i = 2; i < p.length; i += 2) {
    const dx = p[i] - p[i - 2], dy = p[i + 1] - p[i - 1], d = Math.hypot(dx, dy);
    if (left <= d || i === p.length - 2) {
      const f = d > 0 ? Math.min(left / d, 1) : 0;
      return [p[i - 2] + f * dx, p[i - 1] + f * dy, Math.atan2(dy, dx)];
    }
    left -= d;
  }
  return [p[0], p[1], 0];
}

function setSnap(t, s) {
  Object.assign(t, { lane: s.lane, edge: s.edge, index: s.index, pos: s.pos, x: s.x, y: s.y, heading: s.heading,
                     limit: s.speed_limit });
}

async function dropToken(x, y) {
  const s = await api("/api/snap", { x, y });
  const t = { f: { vclass: "passenger", speed: Math.round(0.8 * s.speed_limit) } };
  setSnap(t, s);
  S.tokens.push(t);
  if (!S.win) placeWindow(s.x, s.y);
  select(S.tokens.length - 1);
}

function select(i) {
  S.sel = i;
  const list = $("token-list");
  list.innerHTML = "";
  S.tokens.forEach((t, k) => {
    const li = document.createElement("li");
    li.textContent = `${k}: ${t.f.vtype || t.f.vclass || "vehicle"} on ${t.lane} at ${t.pos.toFixed(1)} m` +
      (t.f.speed !== undefined ? `, ${t.f.speed} m/s` : "") + (t.f.manoeuvre ? `, ${t.f.manoeuvre}` : "");
    li.className = k === i ? "sel" : "";
    li.onclick = () => select(k);
    list.appendChild(li);
  });
  const ed = $("token-editor");
  ed.hidden = i < 0;
  if (i >= 0) {
    const t = S.tokens[i];
    $("tok-lane").textContent = `lane ${t.lane} (edge ${t.edge}, index ${t.index}, ${t.limit} m/s limit)`;
    for (const el of ed.querySelectorAll("[data-key]")) {
      const k = el.dataset.key, v = k === "pos" ? t.pos : t.f[k];
      el.value = v === undefined ? "" : v;
    }
  }
  preview(); redraw();
}

function editToken(ev) {
  const t = S.tokens[S.sel], el = ev.target, k = el.dataset.key;
  if (!t || !k) return;
  const raw = el.value.trim();
  const v = raw === "" ? undefined : (el.type === "number" ? Number(raw) : raw);
  if (k === "pos") {
    if (v === undefined || !isFinite(v)) return;
    t.pos = v; [t.x, t.y, t.heading] = lanePoint(t.lane, v);
  } else if (v === undefined) delete t.f[k]; else t.f[k] = v;
  const keepFocus = document.activeElement;
  select(S.sel);
  keepFocus.focus();
}

// ---- window ---------------------------------------------------------------------------------------
function placeWindow(x, y) {
  S.win = { cx: x, cy: y, yaw: S.win && !S.win.ego ? S.win.yaw : 0 };   // an ego window's yaw is run's, not the user's
  showWindow(); redraw();
}

function showWindow() {
  const w = S.win;
  $("window-info").textContent = w ? `centre ${w.cx.toFixed(1)}, ${w.cy.toFixed(1)} m, yaw ${(w.yaw * 180 / Math.PI).toFixed(0)}° ` +
    `(${WINDOW_M} m square; run's --center windows face east: yaw 0)` : "";
}

// ---- pointer ----------------------------------------------------------------------------------------
let drag = null;
function pointerDown(ev) {
  const r = canvas.getBoundingClientRect(), sx = ev.clientX - r.left, sy = ev.clientY - r.top;
  const [x, y] = toWorld(sx, sy), px = 1 / S.view.s;
  if (S.win) {
    const [hx, hy] = toScreen(...handlePoint(S.win));
    if (Math.hypot(hx - sx, hy - sy) < 10) { drag = { kind: "yaw" }; return; }
  }
  const hit = S.tokens.findIndex((t) => Math.hypot(t.x - x, t.y - y) < Math.max(3, 9 * px));
  if (hit >= 0) { drag = { kind: "token", i: hit, moved: false }; select(hit); return; }
  if (S.mode === "window") { placeWindow(x, y); return; }
  if (S.mode === "token") { dropToken(x, y).catch((e) => { $("token-error").textContent = e.message; }); return; }
  drag = { kind: "pan", sx, sy, ox: S.view.ox, oy: S.view.oy };
  canvas.style.cursor = "grabbing";
}

function pointerMove(ev) {
  const r = canvas.getBoundingClientRect(), sx = ev.clientX - r.left, sy = ev.clientY - r.top;
  const [x, y] = toWorld(sx, sy);
  $("coords").textContent = `x ${x.toFixed(2)}  y ${y.toFixed(2)} m`;
  if (!drag) return;
  if (drag.kind === "pan") { S.view.ox = drag.ox + sx - drag.sx; S.view.oy = drag.oy + sy - drag.sy; }
  else if (drag.kind === "yaw") { S.win.yaw = Math.atan2(y - S.win.cy, x - S.win.cx); showWindow(); }
  else if (drag.kind === "token") { const t = S.tokens[drag.i]; t.x = x; t.y = y; drag.moved = true; }
  redraw();
}

async function pointerUp() {
  const d = drag; drag = null; canvas.style.cursor = "grab";
  if (d && d.kind === "token" && d.moved) {
    const t = S.tokens[d.i];
    try { setSnap(t, await api("/api/snap", { x: t.x, y: t.y })); $("token-error").textContent = ""; }
    catch (e) { $("token-error").textContent = e.message; [t.x, t.y, t.heading] = lanePoint(t.lane, t.pos); }
    select(d.i);
  }
}

function wheel(ev) {
  ev.preventDefault();
  const r = canvas.getBoundingClientRect(), sx = ev.clientX - r.left, sy = ev.clientY - r.top;
  const [x, y] = toWorld(sx, sy), k = Math.exp(-ev.deltaY * 0.0015);
  S.view.s *= k; S.view.ox = sx - x * S.view.s; S.view.oy = sy + y * S.view.s;
  redraw();
}

function setMode(m) {
  S.mode = m;
  for (const b of document.querySelectorAll(".mode")) b.classList.toggle("on", b.id === "mode-" + m);
}

// ---- generate, small multiples, keep -------------------------------------------------------------
function knob(id) {
  const v = $(id).value.trim();
  if (v === "") return null;
  return isNaN(Number(v)) ? v : Number(v);
}

async function generate() {
  const ego = $("ego").value.trim();
  if (!S.win && !ego) { $("gen-status").textContent = "place the window first"; return; }
  const body = { tokens: tokenBody(), density: knob("density"), seed: knob("seed") ?? 0,
                 scenes: knob("scenes") ?? 1, guidance: knob("guidance") };
  if (ego) body.ego = ego; else { body.center = [S.win.cx, S.win.cy]; body.yaw = S.win.yaw; }
  S.busy = true; $("generate").disabled = true; $("gen-status").textContent = "generating…";
  const t0 = performance.now();
  try {
    S.result = await api("/api/generate", body);
    S.scene = 0;
    const w = S.result.scenes[0].window;
    if (ego) { S.win = { cx: w.cx, cy: w.cy, yaw: w.yaw, ego: true }; showWindow(); }
    $("gen-status").textContent = `${S.result.scenes.length} scene(s) in ${((performance.now() - t0) / 1000).toFixed(1)} s. ` +
      `The same with the CLI: ${S.result.command}` + (S.result.warnings.length ? "\n" + S.result.warnings.join("\n") : "");
    $("keep-box").hidden = false;
    showMultiples(); showScene(0);
  } catch (e) { $("gen-status").textContent = e.message; }
  finally { S.busy = false; $("generate").disabled = false; }
}

function showMultiples() {
  const box = $("multiples"); box.innerHTML = "";
  S.result.scenes.forEach((sc, k) => {
    const fig = document.createElement("figure"), cv = document.createElement("canvas"), cap = document.createElement("figcaption");
    cv.width = cv.height = 170;
    const w = sc.window, h = WINDOW_M / 2;
    const view = fit([w.cx - h, w.cy - h, w.cx + h, w.cy + h], 170, 170, 0);
    const c = cv.getContext("2d");
    drawNetwork(c, view, 170, 170, 1);
    drawScene(c, sc, 1 / view.s);
    const n = sc.counts;
    cap.textContent = `${sc.scene}: ${n.placed} placed` + (n.refused + n.dropped ? `, ${n.refused + n.dropped} not seeded` : "") +
      (sc.density_veh_per_km !== null ? `, ${sc.density_veh_per_km} veh/km` : "");
    fig.append(cv, cap); fig.onclick = () => showScene(k);
    box.appendChild(fig);
  });
}

function showScene(k) {
  S.scene = k;
  [...$("multiples").children].forEach((f, i) => f.classList.toggle("sel", i === k));
  const sc = S.result.scenes[k], list = $("agent-list");
  list.innerHTML = "";
  sc.agents.forEach((a, i) => {
    const li = document.createElement("li");
    li.textContent = `${i}: ${a.vtype || a.vclass || "vehicle"} ${a.status}` + (a.speed != null ? `, ${a.speed.toFixed(1)} m/s` : "") +
      (a.source === "user" ? ` (token ${a.token})` : "") + (a.reason ? `: ${a.reason}` : "");
    if (a.status === "refused" || a.status === "dropped") li.className = "bad";
    list.appendChild(li);
  });
  for (const [tk, why] of Object.entries(sc.tokens_lost || {})) {
    const li = document.createElement("li"); li.className = "bad"; li.textContent = `token ${tk}: no vehicle: ${why}`;
    list.appendChild(li);
  }
  $("keep-name").value = `${S.net.name}_${S.result.draft}_${sc.scene}`;
  redraw();
}

async function keep() {
  const sc = S.result.scenes[S.scene];
  S.busy = true; $("keep").disabled = true; $("keep-status").textContent = "writing…";
  try {
    S.kept = await api("/api/keep", { draft: S.result.draft, scene: sc.scene, name: $("keep-name").value.trim(),
                                      openscenario: $("keep-xosc").checked });
    $("keep-status").textContent = `wrote ${S.kept.folder} (${S.kept.files.join(", ")})`;
    $("gui-box").hidden = false; $("gui-status").textContent = ""; showGuiCommand(S.kept.sumo);
  } catch (e) { $("keep-status").textContent = e.message; }
  finally { S.busy = false; $("keep").disabled = false; }
}

// sumo-gui is started by the server where it has a display; otherwise (or if it failed) the page shows the
// command, its path quoted for a shell, to copy
function showGuiCommand(command) {
  $("gui-command").textContent = command; $("gui-command-row").hidden = false; $("gui-copy").textContent = "Copy";
}

async function openGui() {
  S.busy = true; $("open-gui").disabled = true; $("gui-status").textContent = "starting sumo-gui…";
  try {
    S.gui = await api("/api/open", { name: S.kept.name });
    $("gui-status").textContent = S.gui.launched ? `sumo-gui started (process ${S.gui.pid})` : `${S.gui.why}:`;
    showGuiCommand(S.gui.command);
  } catch (e) { $("gui-status").textContent = e.message; }
  finally { S.busy = false; $("open-gui").disabled = false; }
}

async function copyGuiCommand() {
  const text = $("gui-command").textContent;
  try {
    await navigator.clipboard.writeText(text);
    $("gui-copy").textContent = "Copied"; S.copied = text;
  } catch (e) {     // no clipboard here (refused, or not a secure context): the text selected for Ctrl-C
    const r = document.createRange(); r.selectNodeContents($("gui-command"));
    getSelection().removeAllRanges(); getSelection().addRange(r);
    $("gui-copy").textContent = "Selected: Ctrl-C";
  }
}

// ---- fill.json ------------------------------------------------------------------------------------
async function loadFill(body) {
  try {
    S.fill = await api("/api/fill", body);
    buildCells(); dropLayer();
    $("fill-info").textContent = `${S.fill.vehicles} vehicles; lanes coloured by veh/km of their edge, 0 (blue) … ${S.fill.max} (red)`;
    redraw();
  } catch (e) { $("fill-info").textContent = e.message; }
}

// ---- start ----------------------------------------------------------------------------------------
async function start() {
  S.net = await api("/api/network");
  $("net-name").textContent = `Network ${S.net.name}`;
  $("ego-row").hidden = !S.net.demand;
  buildCells();
  S.view = fit(S.net.bounds, canvas.clientWidth, canvas.clientHeight);
  canvas.addEventListener("pointerdown", pointerDown);
  window.addEventListener("pointermove", pointerMove);
  window.addEventListener("pointerup", pointerUp);
  canvas.addEventListener("wheel", wheel, { passive: false });
  window.addEventListener("resize", redraw);
  for (const m of ["pan", "window", "token"]) $("mode-" + m).onclick = () => setMode(m);
  $("fit").onclick = () => { S.view = fit(S.net.bounds, canvas.clientWidth, canvas.clientHeight); redraw(); };
  $("token-editor").addEventListener("change", editToken);
  $("tok-remove").onclick = () => { S.tokens.splice(S.sel, 1); select(-1); };
  $("p_mask").addEventListener("change", () => { S.pMask = knob("p_mask"); preview(); });
  $("generate").onclick = generate;
  $("keep").onclick = keep;
  $("open-gui").onclick = openGui;
  $("gui-copy").onclick = copyGuiCommand;
  $("fill-file").addEventListener("change", async (ev) => {
    const f = ev.target.files[0];
    if (!f) return;
    try { await loadFill({ fill: JSON.parse(await f.text()) }); }
    catch (e) { $("fill-info").textContent = `${f.name}: ${e.message}`; }
  });
  $("fill-load").onclick = () => loadFill({ path: $("fill-path").value.trim() });
  select(-1);
  S.ready = true;
  redraw();
}

start().catch((e) => { document.body.insertAdjacentHTML("afterbegin", `<div class="error">${e.message}</div>`); });
