// The replay page: one recorded session (/timeline.json), scrubbed step by step. Same picture of the environment
// as the live console (draw.js); Q and H are the learner's at each step (re-learned from the log by the server).
"use strict";

const WINDOW = 40;  // steps each side of the chosen one in the detail timeline

const replay = window.replay = { data: null, index: 0, playing: false, timer: null, bySeq: new Map(),
  creditsOf: new Map(), feedbackX: [] };

// ---------------------------------------------------------------- loading
async function load() {
  const data = replay.data = await (await consoleKey.request("/timeline.json")).json();
  data.steps.forEach((s, i) => replay.bySeq.set(`${s.actor}/${s.seq}`, i));
  data.credits.forEach((c, k) => {
    replay.feedbackX.push(stepAxis(c.t));
    c.steps.forEach(({ seq }) => {
      const i = replay.bySeq.get(`${c.actor}/${seq}`);
      if (i === undefined) return;
      if (!replay.creditsOf.has(i)) replay.creditsOf.set(i, []);
      replay.creditsOf.get(i).push(k);
    });
  });
  document.getElementById("who").textContent = `run ${data.run}: ${data.algo} on ${data.env} (layout ${data.layout}),` +
    ` ${data.steps.length} steps, ${data.credits.length} feedback${data.cut ? " (cut: the first steps only)" : ""}`;
  const scrub = document.getElementById("scrub");
  scrub.max = String(Math.max(0, data.steps.length - 1));
  drawCurve(); drawOverview(); setIndex(0);
  replay.ready = true;
}

// Where a time falls on the step axis: step i's action at i, the next one at i + 1.
function stepAxis(t) {
  const s = replay.data.steps;
  let lo = 0, hi = s.length - 1;
  if (!s.length || t < s[0].t) return -0.5;
  while (lo < hi) { const mid = (lo + hi + 1) >> 1; if (s[mid].t <= t) lo = mid; else hi = mid - 1; }
  const next = s[lo + 1];
  return next && next.t > s[lo].t ? lo + (t - s[lo].t) / (next.t - s[lo].t) : lo + 0.5;
}

// ---------------------------------------------------------------- the scene
function drawScene() {
  const cv = document.getElementById("scene"), g = cv.getContext("2d");
  const sc = replay.data.scene, st = replay.data.steps[replay.index];
  g.fillStyle = COLORS.free; g.fillRect(0, 0, cv.width, cv.height);
  if (!sc || !st) { g.fillStyle = "#222"; g.font = "14px monospace"; g.fillText("no picture of this environment", 10, 20); return; }
  drawWorld(cv, sc, st.scene || {}, drawCredited);
}

// The feedback given within a few steps of this one: each credited step's cell (where the agent acted from)
// tinted by its weight. A cell's position before step i is the position after step i - 1 in the same episode.
function cellBefore(i) {
  const s = replay.data.steps, sc = replay.data.scene;
  if (i > 0 && s[i - 1].episode === s[i].episode && s[i - 1].scene) return s[i - 1].scene.agent || s[i - 1].scene.taxi;
  return sc && sc.kind === "maze" ? sc.start : null;
}
function nearCredits() {
  const i = replay.index;
  return replay.data.credits.map((c, k) => ({ c, k, x: replay.feedbackX[k] })).filter(({ x }) => Math.abs(x - i) <= 3);
}
function drawCredited(g, c) {
  nearCredits().forEach(({ c: cr }) => {
    const rgb = cr.value > 0 ? COLORS.good : COLORS.bad;
    cr.steps.forEach(({ seq, weight }) => {
      const j = replay.bySeq.get(`${cr.actor}/${seq}`);
      const cell = j === undefined ? null : cellBefore(j);
      if (!cell) return;
      g.fillStyle = `rgba(${rgb},${Math.min(0.6, 0.12 + 1.2 * weight)})`;
      g.fillRect(cell[1] * c + 1, cell[0] * c + 1, c - 2, c - 2);
    });
  });
}

// ---------------------------------------------------------------- the side panel
function showStep() {
  const st = replay.data.steps[replay.index];
  if (!st) return;
  const names = (replay.data.scene && replay.data.scene.actions) || [];
  document.getElementById("episode").textContent = `episode ${st.episode}`;
  document.getElementById("step").textContent = `step ${st.t_in_episode} (seq ${st.seq})`;
  document.getElementById("action").textContent = `action ${names[st.action] || st.action}`;
  document.getElementById("reward").textContent = `reward ${st.reward}`;
  const tb = document.querySelector("#prefs tbody");
  tb.innerHTML = st.q ? st.q.map((q, a) => `<tr class="${a === st.q.indexOf(Math.max(...st.q)) ? "best" : ""}">` +
    `<td>${names[a] || a}</td><td>${q.toFixed(3)}</td><td>${st.h[a].toFixed(3)}</td></tr>`).join("") : "";
  document.getElementById("alpha").textContent = st.alpha_h === null ? "" : `alpha_h ${st.alpha_h}`;
  const here = new Set(replay.creditsOf.get(replay.index) || []);
  const near = nearCredits();
  here.forEach((k) => { if (!near.some((n) => n.k === k)) near.push({ c: replay.data.credits[k], k }); });
  document.getElementById("near").innerHTML = near.map(({ c, k }) => {
    const where = c.status === "credited" ? "steps " + c.steps.map((s) => `${s.seq} (${s.weight.toFixed(2)})`).join(", ") : c.status;
    return `<li class="${c.value > 0 ? "pos" : "neg"}${here.has(k) ? " here" : ""}">${c.value > 0 ? "+1" : "-1"} ` +
      `${c.teacher} #${c.seq} -> ${where}</li>`;
  }).join("");
}

function drawCurve() {
  const cv = document.getElementById("curve"), pts = replay.data.curve;
  const drawn = drawReturns(cv, pts, pts.length);
  if (!drawn) return;
  const { g, lo, hi, x } = drawn;
  const cur = replay.data.steps[replay.index];
  if (cur) { const k = pts.findIndex((p) => p.episode === cur.episode);
    if (k >= 0) { g.strokeStyle = COLORS.cursor; g.lineWidth = 1; g.beginPath(); g.moveTo(x(k), 0); g.lineTo(x(k), cv.height); g.stroke(); } }
  g.fillStyle = "#555"; g.font = "11px sans-serif"; g.fillText(`return per episode (${lo.toFixed(1)}..${hi.toFixed(1)})`, 6, 12);
}

// ---------------------------------------------------------------- timelines
function valueRange(from, to) {
  let lo = Infinity, hi = -Infinity;
  for (let i = from; i <= to; i++) { const s = replay.data.steps[i]; if (!s || !s.q) continue;
    lo = Math.min(lo, s.q[s.action], s.h[s.action]); hi = Math.max(hi, s.q[s.action], s.h[s.action]); }
  return lo < hi ? [lo, hi] : [lo - 1, hi + 1];
}

function drawDetail() {
  const cv = document.getElementById("detail"), g = cv.getContext("2d"), s = replay.data.steps;
  const i0 = replay.index - WINDOW, w = cv.width / (2 * WINDOW + 1), fbY = 36, top = 70, bottom = cv.height - 18;
  const x = (i) => (i - i0 + 0.5) * w;
  g.clearRect(0, 0, cv.width, cv.height);
  const from = Math.max(0, i0), to = Math.min(s.length - 1, replay.index + WINDOW);
  for (let i = from; i <= to; i++) {  // episode boundaries and step labels
    if (i > 0 && s[i].episode !== s[i - 1].episode) { g.strokeStyle = "#aaa"; g.setLineDash([4, 3]);
      g.beginPath(); g.moveTo(x(i) - w / 2, 0); g.lineTo(x(i) - w / 2, cv.height); g.stroke(); g.setLineDash([]);
      g.fillStyle = "#777"; g.font = "10px sans-serif"; g.fillText(`episode ${s[i].episode}`, x(i) - w / 2 + 3, cv.height - 4); }
  }
  g.fillStyle = "rgba(41,128,185,0.12)"; g.fillRect(x(replay.index) - w / 2, 0, w, cv.height);
  const [lo, hi] = valueRange(from, to), y = (v) => bottom - (bottom - top) * (v - lo) / (hi - lo);
  for (const [key, color] of [["q", COLORS.q], ["h", COLORS.h]]) {  // Q and H of the action taken
    g.strokeStyle = color; g.lineWidth = 2; g.beginPath(); let started = false;
    for (let i = from; i <= to; i++) { if (!s[i].q) continue; const v = s[i][key][s[i].action];
      started ? g.lineTo(x(i), y(v)) : g.moveTo(x(i), y(v)); started = true; }
    g.stroke();
  }
  g.font = "11px sans-serif"; g.fillStyle = COLORS.q; g.fillText("Q(s, a taken)", cv.width - 190, 12);
  g.fillStyle = COLORS.h; g.fillText("H(s, a taken)", cv.width - 100, 12);
  g.fillStyle = "#555"; g.fillText(`${hi.toFixed(2)}`, cv.width - 40, top + 10); g.fillText(`${lo.toFixed(2)}`, cv.width - 40, bottom);
  replay.data.credits.forEach((c, k) => {  // each feedback at its time, lines to the steps it was credited to
    const fx = replay.feedbackX[k];
    if (fx < i0 - 4 || fx > replay.index + WINDOW + 4) return;
    const rgb = c.value > 0 ? COLORS.good : COLORS.bad;
    c.steps.forEach(({ seq, weight }) => { const j = replay.bySeq.get(`${c.actor}/${seq}`); if (j === undefined) return;
      g.strokeStyle = `rgba(${rgb},0.8)`; g.lineWidth = 0.5 + 6 * weight;
      g.beginPath(); g.moveTo(x(fx - 0.5), fbY); g.lineTo(x(j), top); g.stroke(); });
    g.fillStyle = `rgb(${rgb})`; g.beginPath(); g.arc(x(fx - 0.5), fbY - 8, 7, 0, 2 * Math.PI); g.fill();
    g.fillStyle = "#fff"; g.font = "bold 11px sans-serif"; g.fillText(c.value > 0 ? "+" : "-", x(fx - 0.5) - 3, fbY - 4);
    if (c.status !== "credited") { g.fillStyle = "#555"; g.font = "10px sans-serif"; g.fillText(c.status, x(fx - 0.5) + 9, fbY - 4); }
  });
  g.fillStyle = "#555"; g.font = "11px sans-serif"; g.fillText("feedback (line width = credit weight)", 6, 12);
}

function drawOverview() {
  const cv = document.getElementById("overview"), g = cv.getContext("2d"), s = replay.data.steps;
  g.clearRect(0, 0, cv.width, cv.height);
  if (!s.length) return;
  const x = (i) => 4 + (cv.width - 8) * i / Math.max(1, s.length - 1), top = 22, bottom = cv.height - 4;
  const [lo, hi] = valueRange(0, s.length - 1), y = (v) => bottom - (bottom - top) * (v - lo) / (hi - lo);
  const every = Math.max(1, Math.floor(s.length / cv.width));
  for (const [key, color] of [["q", COLORS.q], ["h", COLORS.h]]) {
    g.strokeStyle = color; g.lineWidth = 1; g.beginPath(); let started = false;
    for (let i = 0; i < s.length; i += every) { if (!s[i].q) continue; const v = s[i][key][s[i].action];
      started ? g.lineTo(x(i), y(v)) : g.moveTo(x(i), y(v)); started = true; }
    g.stroke();
  }
  replay.data.credits.forEach((c, k) => { g.fillStyle = `rgba(${c.value > 0 ? COLORS.good : COLORS.bad},0.7)`;
    g.fillRect(x(Math.max(0, replay.feedbackX[k])), c.value > 0 ? 2 : 11, 1.5, 8); });
  g.strokeStyle = COLORS.cursor; g.lineWidth = 2; g.beginPath(); g.moveTo(x(replay.index), 0); g.lineTo(x(replay.index), cv.height); g.stroke();
}

// ---------------------------------------------------------------- scrubbing
function setIndex(i) {
  const n = replay.data.steps.length;
  replay.index = Math.max(0, Math.min(n - 1, Math.round(i)));
  document.getElementById("scrub").value = String(replay.index);
  drawScene(); showStep(); drawDetail(); drawOverview(); drawCurve();
}
replay.setIndex = setIndex;

function play(on) {
  replay.playing = on; clearInterval(replay.timer);
  document.getElementById("play").textContent = on ? "pause" : "play";
  if (!on) return;
  const rate = Number(document.getElementById("speed").value);
  replay.timer = setInterval(() => {
    if (replay.index >= replay.data.steps.length - 1) { play(false); return; }
    setIndex(replay.index + 1);
  }, 1000 / rate);
}

document.getElementById("scrub").addEventListener("input", (ev) => setIndex(Number(ev.target.value)));
document.getElementById("play").addEventListener("click", () => play(!replay.playing));
document.getElementById("speed").addEventListener("change", () => { if (replay.playing) play(true); });
document.getElementById("overview").addEventListener("click", (ev) => {
  const r = ev.target.getBoundingClientRect();
  setIndex((ev.clientX - r.left - 4) / (r.width - 8) * (replay.data.steps.length - 1));
});
document.getElementById("detail").addEventListener("click", (ev) => {
  const r = ev.target.getBoundingClientRect();
  setIndex(replay.index - WINDOW + Math.floor((ev.clientX - r.left) / (r.width / (2 * WINDOW + 1))));
});
document.addEventListener("keydown", (ev) => {
  if (!replay.data || ev.target.id === "scrub") return;  // the slider moves itself with the arrow keys
  if (ev.key === "ArrowRight") setIndex(replay.index + 1);
  else if (ev.key === "ArrowLeft") setIndex(replay.index - 1);
  else if (ev.key === " ") { ev.preventDefault(); play(!replay.playing); }
});
load().catch((e) => { document.getElementById("who").textContent = `cannot load the log: ${e.message}`; });
