// Drawing shared by the live console (console.js) and the replay page (replay.js): the environment's picture and
// the learning curve. Loaded before either page's own script; its names are globals of the page.
"use strict";

const COLORS = { wall: "#333333", free: "#ffffff", grid: "#dddddd", goal: "#f1c40f", start: "#cfe3f5",
  agent: "#2980b9", taxi: "#e67e22", full: "#8e44ad", good: "46,139,87", bad: "192,57,43",
  q: "#2d3142", h: "#d35400", cursor: "#2980b9" };

function disc(g, [r, q], c, color, scale = 0.32) {
  g.fillStyle = color; g.beginPath(); g.arc(q * c + c / 2, r * c + c / 2, c * scale, 0, 2 * Math.PI); g.fill();
}

// The environment on a square canvas: `layout` is the static scene (maze walls, or taxi stands), `where` the
// positions after a step (agent; or taxi, passenger, destination), none before the first. `tint(g, c)` colours
// cells (the credited steps) over the layout and under the grid; c is the cell size in pixels.
// The layout never changes in a run: it is drawn once into a canvas of its own and copied in with one drawImage
// (a maze's cells were a hundred draw calls a step, each work for the renderer and the GPU process).
const layers = new WeakMap();  // layout -> its picture, at the size of the canvas it was drawn for
function drawLayout(g, s, c) {
  if (s.kind === "maze") {
    for (let r = 0; r < s.size; r++) for (let q = 0; q < s.size; q++) {
      g.fillStyle = s.walls[r][q] ? COLORS.wall : (r === s.start[0] && q === s.start[1] ? COLORS.start : COLORS.free);
      g.fillRect(q * c, r * c, c, c);
    }
    g.fillStyle = COLORS.goal; g.fillRect(s.goal[1] * c + 4, s.goal[0] * c + 4, c - 8, c - 8);
  } else if (s.kind === "taxi") {
    s.stands.forEach(([r, q], i) => { g.fillStyle = "#ecf0f1"; g.fillRect(q * c + 2, r * c + 2, c - 4, c - 4);
      g.fillStyle = "#555"; g.font = `${c / 3}px sans-serif`; g.fillText(s.stand_names[i], q * c + 6, r * c + c / 3 + 4); });
  }
}
function layoutLayer(cv, s, c) {
  let layer = layers.get(s);
  if (!layer || layer.width !== cv.width || layer.height !== cv.height) {
    layer = document.createElement("canvas"); layer.width = cv.width; layer.height = cv.height;
    const lg = layer.getContext("2d"); lg.fillStyle = COLORS.free; lg.fillRect(0, 0, cv.width, cv.height);
    drawLayout(lg, s, c); layers.set(s, layer);
  }
  return layer;
}
function drawWorld(cv, layout, where, tint) {
  const g = cv.getContext("2d"), s = layout, c = cv.width / s.size;
  g.drawImage(layoutLayer(cv, s, c), 0, 0);
  tint(g, c);
  g.strokeStyle = COLORS.grid; g.lineWidth = 1; g.beginPath();  // the grid: one path, one stroke
  for (let i = 0; i <= s.size; i++) { g.moveTo(i * c, 0); g.lineTo(i * c, s.size * c); g.moveTo(0, i * c); g.lineTo(s.size * c, i * c); }
  g.stroke();
  if (s.kind === "taxi") {
    g.strokeStyle = "#222"; g.lineWidth = 5;
    s.walls_east.forEach(([r, q]) => { g.beginPath(); g.moveTo((q + 1) * c, r * c); g.lineTo((q + 1) * c, (r + 1) * c); g.stroke(); });
  }
  if (!where) return;
  if (where.agent) disc(g, where.agent, c, COLORS.agent);
  if (where.taxi) {
    const dest = s.stands[where.dest];
    g.strokeStyle = COLORS.goal; g.lineWidth = 6; g.strokeRect(dest[1] * c + 3, dest[0] * c + 3, c - 6, c - 6);
    disc(g, where.taxi, c, where.passenger === 4 ? COLORS.full : COLORS.taxi);
    if (where.passenger < 4) disc(g, s.stands[where.passenger], c, COLORS.full, 0.18);
  }
}

// The return of each episode in `pts` as a line over `slots` places (>= pts.length). Returns the range and the
// x of an episode's place, for what a page draws on top; null when there is nothing to draw.
function drawReturns(cv, pts, slots) {
  const g = cv.getContext("2d");
  g.clearRect(0, 0, cv.width, cv.height);
  if (!pts.length) return null;
  const ys = pts.map((p) => p.return), lo = Math.min(...ys, 0), hi = Math.max(...ys, 1);
  const x = (i) => 5 + (cv.width - 10) * i / Math.max(1, slots - 1);
  g.strokeStyle = COLORS.q; g.lineWidth = 2; g.beginPath();
  pts.forEach((p, i) => { const y = cv.height - 5 - (cv.height - 10) * (p.return - lo) / (hi - lo);
    i ? g.lineTo(x(i), y) : g.moveTo(x(i), y); });
  g.stroke();
  return { g, lo, hi, x };
}
