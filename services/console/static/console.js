// The console page: draws the run, sends the person's feedback, paint times and controls over one WebSocket.
// Times: the page's clock is performance.timeOrigin + performance.now() (monotonic, in seconds); its offset to
// the console's system clock is estimated as NTP does, from the ping with the smallest round trip.
"use strict";

const pageNow = () => (performance.timeOrigin + performance.now()) / 1000;
const pageTime = (ts) => (performance.timeOrigin + ts) / 1000;  // an event's or a frame's DOMHighResTimeStamp

const hitl = window.hitl = {
  ws: null, hello: null, me: null, clock: { offset: 0, target: 0, slewedAt: 0, rtt: Infinity, ready: false, samples: [] },
  step: null, prefs: null, curve: [], positions: new Map(), trail: [], mine: new Map(),
  shownLog: [], pressLog: [], paused: false, ended: false, rate: null, pending: null, rejected: {},
  face: null, faceFeedback: [],
};

function send(obj) { if (hitl.ws && hitl.ws.readyState === 1) hitl.ws.send(JSON.stringify(obj)); }

// ---------------------------------------------------------------- clock
// The clock is ready once one round trip took at most CLOCK_GOOD_RTT (its offset is then within half of it), or
// after CLOCK_SAMPLES tries on a slow network. A page busy loading answers its first pings late (0.34-0.44 s round
// trips measured), and an offset taken from them is corrected by 0.2 s a second later: the paints around the
// correction would go back in time and be dropped.
// Once ready, a better estimate is taken in at once if it is ahead, and slewed in at CLOCK_SLEW seconds per
// second if it is behind (as NTP slews): the page's system time never runs backwards, so every paint reaches
// the console in order, and a press is credited over the same paints the page logged (a loaded machine had
// its first round trips take seconds, and a correction of 2 s back had the console drop 2 s of paints).
const CLOCK_GOOD_RTT = 0.05, CLOCK_SAMPLES = 16, CLOCK_SLEW = 0.5;
function ping() { send({ type: "ping", t0: pageNow(), ready: hitl.clock.ready }); }
function onPong(m) {
  const t3 = pageNow();
  hitl.pongs = (hitl.pongs || 0) + 1;
  const rtt = (t3 - m.t0) - (m.t2 - m.t1);
  const offset = ((m.t1 - m.t0) + (m.t2 - t3)) / 2;
  const c = hitl.clock;
  c.samples.push({ offset, rtt });
  if (c.samples.length > 16) c.samples.shift();
  const best = c.samples.reduce((a, b) => (b.rtt < a.rtt ? b : a));
  c.target = best.offset; c.rtt = Math.max(0, best.rtt);
  if (!c.ready) c.offset = c.target;
  if (!c.ready && (c.rtt <= CLOCK_GOOD_RTT || c.samples.length >= CLOCK_SAMPLES)) {
    c.ready = true; c.slewedAt = t3;
    ping();  // tells the console (a run waiting for its first page starts now)
  }
  setText("clock", `clock offset ${(c.offset * 1000).toFixed(1)} ms (round trip ${(c.rtt * 1000).toFixed(1)} ms)`);
}
function offsetAt(tPage) {  // the offset in force at page time tPage (see CLOCK_SLEW)
  const c = hitl.clock;
  if (c.ready && c.target !== c.offset) {
    const room = CLOCK_SLEW * Math.max(0, tPage - c.slewedAt);
    c.offset = c.target > c.offset ? c.target : Math.max(c.target, c.offset - room);
  }
  c.slewedAt = Math.max(c.slewedAt, tPage);
  return c.offset;
}
function stamp(tPage) { return { t_page: tPage, offset: offsetAt(tPage), rtt: Math.min(hitl.clock.rtt, 60) }; }

// ---------------------------------------------------------------- drawing (shared with the replay page: draw.js)
function drawScene() {
  const cv = document.getElementById("scene"), g = cv.getContext("2d");
  const s = hitl.hello && hitl.hello.scene, st = hitl.step;
  if (!s) {  // no drawing of ours: the env's own picture from the actor, else the observation's numbers
    g.fillStyle = COLORS.free; g.fillRect(0, 0, cv.width, cv.height);
    if (hitl.frame) {
      const f = hitl.frame, k = Math.min(cv.width / f.width, cv.height / f.height);
      g.drawImage(f, (cv.width - f.width * k) / 2, (cv.height - f.height * k) / 2, f.width * k, f.height * k);
    } else {
      g.fillStyle = "#222"; g.font = "14px monospace";
      g.fillText(st ? `obs ${JSON.stringify(st.next_obs)}` : "waiting for the first step", 10, 20);
    }
    return;
  }
  drawWorld(cv, s, st && st.scene, drawTrail);
}
function legend(s) {
  const trail = "Tinted cells: the steps your latest feedback was credited to (green +1, red -1; darker = more weight).";
  if (!s) return "The environment's own picture, rendered by the actor after each step.";
  if (s.kind === "maze") return `Blue: the agent. Yellow: the goal. Dark: walls. ${trail}`;
  return `Orange: the taxi (purple while carrying). Purple dot: the passenger. Yellow frame: the destination. ${trail}`;
}
function cellOf(seq) { const sc = hitl.positions.get(seq); return sc && (sc.agent || sc.taxi); }
function drawTrail(g, c) {
  // The newest credits of this person: each credited step's cell tinted by the weight it got.
  const recent = hitl.trail.filter((t) => t.teacher_id === hitl.me).slice(-3);
  recent.forEach((t, age) => {
    const rgb = t.value > 0 ? COLORS.good : COLORS.bad;
    t.steps.forEach(({ seq, weight }) => {
      const cell = cellOf(seq);
      if (!cell) return;
      const alpha = Math.min(0.55, 0.15 + 2 * weight) * (age + 1) / recent.length;
      g.fillStyle = `rgba(${rgb},${alpha})`; g.fillRect(cell[1] * c + 1, cell[0] * c + 1, c - 2, c - 2);
    });
  });
}

function drawCurve() {
  const cv = document.getElementById("curve"), pts = hitl.curve;
  const drawn = drawReturns(cv, pts, Math.max(hitl.hello ? hitl.hello.episodes : 1, pts.length));
  if (!drawn) return;
  const { g, lo, hi } = drawn;
  g.fillStyle = "#555"; g.font = "11px sans-serif"; g.fillText(`return (${lo.toFixed(1)}..${hi.toFixed(1)}) per episode`, 6, 12);
}

// ---------------------------------------------------------------- painting a step, and saying when
function onStep(m) {
  if (m.t_in_episode === 0) hitl.episodeReturn = 0;
  hitl.episodeReturn = (hitl.episodeReturn || 0) + m.reward;
  hitl.positions.set(m.seq, m.scene || {});
  if (hitl.positions.size > 400) hitl.positions.delete(hitl.positions.keys().next().value);
  hitl.pending = m;
  requestAnimationFrame(paint);
}

function paint(ts) {
  const m = hitl.pending;
  if (!m) return;
  hitl.pending = null;
  hitl.step = m;
  later.delete(drawScene);  // drawn here anyway
  drawScene(); showStatus(); flushPrefs(); flushLater();
  const drawn = performance.now();
  // What was drawn appears with the frame this callback produces; the next frame's callback time is when
  // that frame was presented (never earlier than the drawing itself).
  requestAnimationFrame((next) => reportShown(m, pageTime(Math.max(next, drawn))));
}

function reportShown(m, tPage) {
  if (hitl.clock.ready) {
    const st = stamp(tPage);
    send({ type: "shown", seq: m.seq, actor: m.actor, ...st });
    hitl.shownLog.push({ seq: m.seq, actor: m.actor, episode: m.episode, t_page: tPage, t_sys: tPage + st.offset, info: m.info,
      t_action: m.t_action });
    if (hitl.shownLog.length > 2000) hitl.shownLog.shift();
    for (const fn of hitl.onShown || []) fn(m, tPage);
  }
}

// ---------------------------------------------------------------- teaching
// Every press is kept (in this tab's sessionStorage, so a reload keeps it too) until the learner's Credit for it
// arrives, and re-sent after a reconnect with its page id and press number: the console gives it the seq it had,
// and the learner, which drops a seq it has consumed, answers with a `duplicate` Credit. Nothing is credited twice.
const store = window.sessionStorage;
function newId() { const b = new Uint8Array(12); crypto.getRandomValues(b); return [...b].map((x) => x.toString(16).padStart(2, "0")).join(""); }
hitl.pageId = store.getItem("hitl-page-id") || newId();
store.setItem("hitl-page-id", hitl.pageId);
hitl.held = JSON.parse(store.getItem("hitl-held") || "[]");  // presses not yet acknowledged, oldest first
hitl.dropped = [];  // presses the console refused, with the reason
function keepHeld() { store.setItem("hitl-held", JSON.stringify(hitl.held)); }
function nextPress() { const n = Number(store.getItem("hitl-press-no") || "0"); store.setItem("hitl-press-no", String(n + 1)); return n; }
function acknowledge(m) {
  const i = hitl.held.findIndex((h) => h.seq === m.seq && h.teacher === m.teacher_id);
  if (i >= 0) { hitl.held.splice(i, 1); keepHeld(); redrawLater(showTrail); }
}
const RESHOW_S = 10;  // s of paints before the oldest held press re-sent with it (longer than any assumed delay)
function reshow() {  // after a reconnect: the paints the held presses may be about, so that a restarted console
  // (which lost this page's screen timeline) lists the steps they were about, at the times they were shown
  if (!hitl.held.length) return;
  const since = Math.min(...hitl.held.map((h) => h.t_page + h.offset)) - RESHOW_S;
  for (const s of hitl.shownLog) {
    if (s.t_sys < since) continue;
    send({ type: "shown", seq: s.seq, actor: s.actor, t_page: s.t_page, offset: s.t_sys - s.t_page,
      rtt: Math.min(hitl.clock.rtt, 60), t_action: s.t_action, resend: true });
    hitl.reshown = (hitl.reshown || 0) + 1;
  }
}
function resendHeld() {  // after (re)connecting: the presses not yet acknowledged, paced below the press limit
  const queue = hitl.held.slice();
  const next = () => {
    const h = queue.shift();
    if (!h || !hitl.ws || hitl.ws.readyState !== 1) return;
    send({ type: "feedback", value: h.value, source: h.source, t_page: h.t_page, offset: h.offset, rtt: h.rtt,
      press: h.press, resend: true });
    hitl.resent = (hitl.resent || 0) + 1;
    setTimeout(next, 200);
  };
  next();
}

function give(value, tPage, source) {
  if (!hitl.clock.ready || hitl.ended) return;
  const press = nextPress(), st = stamp(tPage);
  hitl.held.push({ press, value, source, ...st, teacher: hitl.me, seq: null }); keepHeld();
  send({ type: "feedback", value, source, ...st, press });
  hitl.pressLog.push({ value, t_page: tPage, t_sys: tPage + st.offset, source, press });
  const b = document.getElementById(value > 0 ? "good" : "bad");
  b.classList.add("flash"); setTimeout(() => b.classList.remove("flash"), 120);
}
hitl.give = give;

document.addEventListener("keydown", (ev) => {
  const good = ["+", "=", "ArrowUp", "Add"].includes(ev.key) || ev.code === "NumpadAdd";
  const bad = ["-", "_", "ArrowDown", "Subtract"].includes(ev.key) || ev.code === "NumpadSubtract";
  if (!good && !bad) return;
  ev.preventDefault();
  if (ev.repeat) return;
  give(good ? 1 : -1, pageTime(ev.timeStamp), "key");
});
document.getElementById("good").addEventListener("pointerdown", (ev) => give(1, pageTime(ev.timeStamp), "button"));
document.getElementById("bad").addEventListener("pointerdown", (ev) => give(-1, pageTime(ev.timeStamp), "button"));
document.getElementById("pause").addEventListener("click", () => send({ type: "control", command: hitl.paused ? "resume" : "pause" }));
document.getElementById("end").addEventListener("click", () => {
  if (confirm("End the run for everyone?")) send({ type: "control", command: "end" }); });
document.getElementById("pace").addEventListener("change", (ev) => send({ type: "control", command: "pace", rate: Number(ev.target.value) }));

// ---------------------------------------------------------------- webcam
async function startCamera() {
  const video = document.getElementById("video");
  const stream = await navigator.mediaDevices.getUserMedia({ video: { width: 320, height: 240 }, audio: false });
  video.srcObject = stream; await video.play();
  const grab = document.createElement("canvas"); grab.width = 320; grab.height = 240;
  const g = grab.getContext("2d");
  hitl.cameraOn = true;
  const every = 1000 / Math.min(10, (hitl.hello && hitl.hello.max_frame_rate) || 10);
  const tick = () => {
    if (!hitl.cameraOn || !hitl.clock.ready || hitl.ws.readyState !== 1) return;
    const tPage = pageNow();
    g.drawImage(video, 0, 0, grab.width, grab.height);
    grab.toBlob(async (blob) => {
      if (!blob) return;
      const jpeg = new Uint8Array(await blob.arrayBuffer());
      const buf = new Uint8Array(8 + jpeg.length);
      new DataView(buf.buffer).setFloat64(0, tPage, true);
      buf.set(jpeg, 8);
      hitl.ws.send(buf);
      hitl.framesSent = (hitl.framesSent || 0) + 1;
    }, "image/jpeg", 0.8);
  };
  hitl.cameraTimer = setInterval(tick, every);
  document.getElementById("camera").textContent = "webcam on";
}
function stopCamera() {
  if (!hitl.cameraOn) return;
  hitl.cameraOn = false; clearInterval(hitl.cameraTimer);
  const video = document.getElementById("video");
  if (video.srcObject) video.srcObject.getTracks().forEach((t) => t.stop());
  document.getElementById("camera").textContent = "webcam off (run over)";
}
hitl.startCamera = startCamera;
document.getElementById("camera").addEventListener("click", () => startCamera().catch((e) => {
  document.getElementById("face").textContent = `webcam: ${e.message}`; }));

// ---------------------------------------------------------------- the socket
function onMessage(m) {
  switch (m.type) {
    case "hello":
      hitl.hello = m; hitl.me = m.teacher_id; hitl.rate = m.rate; hitl.paused = m.paused; hitl.ended = m.ended;
      hitl.curve = m.curve.slice(); hitl.trail = m.trail.slice();
      document.getElementById("who").textContent = `you are teacher ${m.teacher_id} - run ${m.run}, ${m.algo} on ${m.env}`;
      document.getElementById("webcam").hidden = !m.camera;
      document.getElementById("legend").textContent = legend(m.scene);
      document.getElementById("pace").value = String(m.rate);
      drawScene(); drawCurve(); showStatus(); break;
    case "pong": onPong(m); break;
    case "frame": {
      const img = new Image();
      img.onload = () => { hitl.frame = img; hitl.frameSeq = m.seq; drawScene(); };
      img.src = `data:image/${m.format};base64,${m.data}`;
      break;
    }
    case "step": onStep(m); break;
    case "prefs": onPrefs(m); break;
    case "episode": hitl.curve.push(m); drawCurve(); break;
    case "sent": {
      const h = hitl.held.find((x) => x.press === m.press);
      if (h) { h.seq = m.seq; h.teacher = hitl.me; keepHeld(); }
      if (!hitl.mine.has(m.seq)) hitl.mine.set(m.seq, { seq: m.seq, value: m.value, t_reaction: m.t_reaction, credit: null });
      redrawLater(showTrail); break;
    }
    case "credit":
      if (m.teacher_id === hitl.me) acknowledge(m);
      if (m.status === "duplicate") {  // an acknowledgement of a re-sent press, not a second credit
        if (m.teacher_id === hitl.me && hitl.mine.has(m.seq) && !hitl.mine.get(m.seq).credit) hitl.mine.get(m.seq).credit = m;
        break;
      }
      hitl.trail.push(m); if (hitl.trail.length > 200) hitl.trail.shift();
      if (m.teacher_id === hitl.me && hitl.mine.has(m.seq)) { hitl.mine.get(m.seq).credit = m; redrawLater(showTrail); }
      if (m.teacher_id === hitl.me && m.delay) { hitl.delayNext = m.delay; redrawLater(showDelayLater); }
      redrawLater(drawScene); break;
    case "control": hitl.paused = m.paused; hitl.rate = m.rate; hitl.ended = m.ended; showStatus();
      if (m.ended) stopCamera(); break;
    case "face": hitl.face = m; document.getElementById("face").textContent =
      m.label ? `expression: ${m.label} (${m.confidence.toFixed(2)})` : "expression: no face"; break;
    case "face_feedback": hitl.faceFeedback.push(m);
      document.getElementById("facefb").textContent = `face feedback ${m.value > 0 ? "+1" : "-1"} (${m.teacher_id} #${m.seq})`; break;
    case "rejected": {
      hitl.rejected[m.reason] = (hitl.rejected[m.reason] || 0) + 1;
      const i = m.press === null || m.press === undefined ? -1 : hitl.held.findIndex((h) => h.press === m.press);
      if (i >= 0) { hitl.dropped.push({ ...hitl.held[i], reason: m.reason }); hitl.held.splice(i, 1); keepHeld(); showTrail(); }
      break;
    }
    case "refused": hitl.refused = m; document.getElementById("who").textContent = `not connected: ${m.why}`; break;
  }
}

async function loginParams() {
  if (hitl.login) return hitl.login;
  const q = new URLSearchParams(location.search);
  const params = new URLSearchParams();
  for (const k of ["name", "teacher", "password"]) if (q.get(k)) params.set(k, q.get(k));
  const settings = await (await consoleKey.request("/settings")).json();
  if (settings.login && !params.get("password")) {  // --security: a teacher name and its password
    params.set("teacher", prompt("teacher name") || "");
    params.set("password", prompt("password") || "");
  }
  params.set("page", hitl.pageId);
  return (hitl.login = params);
}

async function connect() {
  let params;
  try {
    params = await loginParams();
    params.set("key", await consoleKey.get());
    // after a close, wait until the console answers plain HTTP: Chromium delays a WebSocket after failed ones by
    // up to seconds (its throttle), and a restarted console would wait for the page
    if (hitl.closed) await consoleKey.request("/settings", { cache: "no-store" });
  } catch (e) {
    if (!e.refused) return reconnectLater();  // the console is restarting
    hitl.refused = { reason: "key", why: e.message };
    document.getElementById("who").textContent = `not connected: ${e.message}`;
    return;
  }
  const ws = hitl.ws = new WebSocket(`${location.protocol === "https:" ? "wss" : "ws"}://${location.host}/ws?${params}`);
  ws.binaryType = "arraybuffer";
  ws.onopen = () => {  // a burst until the clock is ready, then a ping every 2 s
    hitl.closed = false;
    hitl.burst = setInterval(() => (hitl.clock.ready ? clearInterval(hitl.burst) : ping()), 60);
    hitl.pinger = setInterval(ping, 2000);
  };
  ws.onmessage = (ev) => {
    const m = JSON.parse(ev.data); onMessage(m);
    if (m.type === "hello") {
      (hitl.helloAt = hitl.helloAt || []).push(pageNow());  // (when the page got in, each time)
      if (hitl.connections) reshow();
      hitl.connections = (hitl.connections || 0) + 1; resendHeld();
    }
  };
  ws.onclose = () => { clearInterval(hitl.pinger); clearInterval(hitl.burst); hitl.closed = true;
    document.getElementById("who").textContent += " (disconnected)";
    if (!hitl.ended && !hitl.refused) reconnectLater(); };
}
document.getElementById("invite").addEventListener("click", async () => {
  const box = document.getElementById("invited"); box.value = await consoleKey.invite(); box.hidden = false; box.select();
});
// a restarted console: the page comes back by itself (every 0.25 s: a refused try costs nothing; it is back in seconds)
function reconnectLater() { setTimeout(connect, 250); }
connect();
