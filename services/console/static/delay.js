// The person's reaction delay as the learner now estimates it (each Credit of theirs carries it: `delay`, a
// density over 0-6 s in bins, its median and 10th-90th percentiles): a small plot beside the feedback trail.
// Loaded after draw.js and before console.js, which calls showDelay for each of this person's credits.
"use strict";

function showDelay(d) {
  hitl.delay = d;
  const cv = document.getElementById("delay"), g = cv.getContext("2d");
  const w = cv.width, h = cv.height, pad = 14, maxS = 6;
  const dens = d.probs.map((p) => p / d.bin_s), top = Math.max(...dens, 1e-9);
  const x = (s) => (s / maxS) * w, y = (v) => h - pad - (v / top) * (h - 2 * pad);
  g.clearRect(0, 0, w, h);
  g.fillStyle = "rgba(41,128,185,0.18)"; g.fillRect(x(d.p10_s), pad / 2, x(d.p90_s) - x(d.p10_s), h - pad * 1.5);
  g.strokeStyle = COLORS.cursor; g.lineWidth = 2; g.beginPath();
  dens.forEach((v, i) => { const s = (i + 0.5) * d.bin_s; if (s <= maxS) (i ? g.lineTo : g.moveTo).call(g, x(s), y(v)); });
  g.stroke();
  g.strokeStyle = "#c0392b"; g.lineWidth = 2; g.beginPath(); g.moveTo(x(d.median_s), pad / 2); g.lineTo(x(d.median_s), h - pad); g.stroke();
  g.fillStyle = "#555"; g.font = "10px sans-serif";
  for (let s = 0; s <= maxS; s += 1) g.fillText(`${s}s`, Math.min(x(s), w - 14), h - 2);
  document.getElementById("delaytext").textContent = `median ${d.median_s.toFixed(2)} s ` +
    `(80% within ${d.p10_s.toFixed(2)}-${d.p90_s.toFixed(2)} s), from ${d.feedbacks} presses` +
    (d.returning ? " (counting your earlier sessions: welcome back)" : d.feedbacks ? "" : " (the learner's starting assumption)");
}
