// A scripted person for the console page (not loaded by the page itself: `python -m services.console.scripted`
// and the tests inject it). It watches each step as it is painted and, with probability p, presses + or - by
// the paper's rule (+1 when the step brought the agent closer to its target or reached a sub-goal) after a
// human-like lag drawn uniformly from [lagMin, lagMax] seconds after the paint, or, given `lags` (a plan drawn
// by `services/console/lags.py`: lags[episode][step in episode], seconds), the planned lag of that step. The
// presses are keyboard events on the page, so they take the same path as a person's.
"use strict";
window.hitlScriptedPerson = function (opts) {
  const o = Object.assign({ p: 0.5, lagMin: 0.3, lagMax: 1.5, seed: 1, lags: null }, opts || {});
  let s = o.seed >>> 0;
  const rand = () => {  // mulberry32: a small seeded generator, so a run can be repeated
    s = (s + 0x6D2B79F5) >>> 0; let t = s;
    t = Math.imul(t ^ (t >>> 15), t | 1); t ^= t + Math.imul(t ^ (t >>> 7), t | 61);
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
  const planned = window.hitlScriptedPlan = [];
  window.hitl.onShown = (window.hitl.onShown || []).concat([(m, tPage) => {
    const info = m.info || {};
    if (info.target_distance_before === undefined || rand() >= o.p) return;
    const good = info.subgoal_reached > 0 || info.target_distance_after < info.target_distance_before;
    const u = rand();  // drawn either way, so a plan leaves the press decisions as they were
    const row = o.lags && o.lags[Math.min(m.episode, o.lags.length - 1)];
    const lag = row ? row[m.t_in_episode % row.length] : o.lagMin + (o.lagMax - o.lagMin) * u;
    const due = tPage + lag;
    planned.push({ seq: m.seq, episode: m.episode, t: m.t_in_episode, value: good ? 1 : -1, lag, due });
    const wait = Math.max(0, (due - (performance.timeOrigin + performance.now()) / 1000) * 1000);
    setTimeout(() => document.dispatchEvent(new KeyboardEvent("keydown", { key: good ? "+" : "-", bubbles: true })), wait);
  }]);
  return o;
};
