// The page's text panels (the status line, what the agent prefers, this person's feedback trail) and when each is
// redrawn: only what changed, and a press's answers with the next step's paint. Loaded after delay.js and before
// console.js, whose `hitl` state they show.
"use strict";

function showPrefs() {
  const p = hitl.prefs, tb = document.querySelector("#prefs tbody");
  if (!p || !p.q) return;
  const names = (hitl.hello.scene && hitl.hello.scene.actions) || p.q.map((_, i) => `a${i}`);
  const score = p.q.map((q, i) => p.alpha_q * q + p.alpha_h * p.h[i]);
  const best = score.indexOf(Math.max(...score));
  while (tb.rows.length < p.q.length) { const tr = tb.insertRow(); for (let j = 0; j < 4; j++) tr.insertCell(); }
  while (tb.rows.length > p.q.length) tb.deleteRow(-1);
  p.q.forEach((q, i) => setRow(tb.rows[i], i === best ? "best" : "", [names[i], q.toFixed(3), p.h[i].toFixed(3), score[i].toFixed(3)]));
  setText("alpha", `alpha_q ${p.alpha_q}  alpha_h ${p.alpha_h.toFixed(4)}  (weights v${p.weights_version})`);
}

// Tables and lists are written in place, a cell or an item at a time: rebuilt whole (innerHTML), every row was
// re-created, styled, laid out and painted again for each step or press, much of the page's layout work (a trace
// of a paced run). Text goes in as text, never as markup.
function setRow(tr, cls, texts) {
  if (tr.className !== cls) tr.className = cls;
  texts.forEach((t, j) => { if (tr.cells[j].textContent !== t) tr.cells[j].textContent = t; });
}

// A DOM write that changes nothing still costs a style pass, a layout and a frame: write only changes.
function setText(id, text) { const el = document.getElementById(id); if (el.textContent !== text) el.textContent = text; }
function showStatus() {
  const st = hitl.step;
  if (st) {
    setText("episode", `episode ${st.episode}`);
    setText("step", `step ${st.t_in_episode}`);
    setText("return", `return ${(hitl.episodeReturn || 0).toFixed(2)}`);
  }
  setText("runstate", hitl.ended ? "run over" : hitl.paused ? "paused" : `${hitl.rate} steps/s`);
  setText("pause", hitl.paused ? "resume" : "pause");
}

// Preferences follow the weights, which at a person's pace change many times a step (idle-time updates: 14 prefs/s
// at 2 steps/s, measured), each re-render a layout and a frame: the newest is shown with the next step's paint,
// or PREFS_EVERY s after the last one shown.
const PREFS_EVERY = 0.5;
function onPrefs(m) {
  hitl.prefs = m; hitl.prefsDirty = true;
  if (!hitl.prefsTimer) hitl.prefsTimer = setTimeout(flushPrefs, Math.max(0, (hitl.prefsShownAt || 0) + PREFS_EVERY * 1000 - performance.now()));
}
function flushPrefs() {
  clearTimeout(hitl.prefsTimer); hitl.prefsTimer = null;
  if (hitl.prefsDirty) { hitl.prefsDirty = false; hitl.prefsShownAt = performance.now(); showPrefs(); }
}

// What a press brings back (its sent, its Credit, the learner's acknowledgement: the trail, the tint, the delay
// plot) is drawn with the next step's paint, or LATER_S s after it arrived when no step comes first (paused, a
// slow pace). Each drawn frame costs the renderer, its compositor and the GPU process; drawn in a frame of their
// own, a press's answers were about a quarter of a paced run's frames (a trace: 103 frames in 20 s at 2 steps/s).
const LATER_S = 0.5;
const later = new Set();
function redrawLater(fn) { later.add(fn); if (!hitl.laterTimer) hitl.laterTimer = setTimeout(flushLater, LATER_S * 1000); }
function flushLater() {
  clearTimeout(hitl.laterTimer); hitl.laterTimer = null;
  const f = [...later]; later.clear(); f.forEach((g) => g());
}
function showDelayLater() { if (hitl.delayNext) { const d = hitl.delayNext; hitl.delayNext = null; showDelay(d); } }

const trailItems = new Map();  // press seq (or "note") -> its <li>, kept while the press is among the newest 30
function trailItem(key, cls, text) {
  let li = trailItems.get(key);
  if (!li) { li = document.createElement("li"); trailItems.set(key, li); }
  if (li.className !== cls) li.className = cls;
  if (li.textContent !== text) li.textContent = text;
  return li;
}
function trailLine(f) {
  const where = f.credit ? (f.credit.status === "credited"
    ? "steps " + f.credit.steps.map((s) => `${s.seq} (${s.weight.toFixed(2)})`).join(", ") : f.credit.status) : "...";
  return `${f.value > 0 ? "+1" : "-1"} #${f.seq} -> ${where}`;
}
function showTrail() {
  const ol = document.getElementById("trail"), items = [];
  const waiting = hitl.held.length, dropped = hitl.dropped.length;  // kept until the learner acknowledges them
  if (waiting || dropped) items.push(trailItem("note", "", `${waiting} press(es) waiting for the learner` +
    (dropped ? `, ${dropped} dropped (${[...new Set(hitl.dropped.map((d) => d.reason))].join(", ")})` : "")));
  for (const f of [...hitl.mine.values()].slice(-30).reverse()) items.push(trailItem(f.seq, f.value > 0 ? "pos" : "neg", trailLine(f)));
  const shown = new Set(items);
  for (const [key, li] of trailItems) if (!shown.has(li)) { li.remove(); trailItems.delete(key); }
  items.forEach((li, i) => { if (ol.children[i] !== li) ol.insertBefore(li, ol.children[i] || null); });
}
