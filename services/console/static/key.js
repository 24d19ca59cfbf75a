// The page's key to its console (services/console/door.py). The printed address carries a one-use entry key in its
// fragment (#token=...), which never reaches a server: the page reads it, removes it from the address bar, and
// trades it for a session key that it keeps in this tab's sessionStorage (a reload keeps it; no other origin can
// read it) and presents itself on every request and on the WebSocket. No cookie: nothing the browser sends by
// itself to another port of 127.0.0.1 opens the console.
"use strict";

const consoleKey = window.consoleKey = (() => {
  const STORE = "hitl-console-key";
  const entry = new URLSearchParams(location.hash.slice(1)).get("token");
  if (location.hash) history.replaceState(history.state, "", location.pathname + location.search);
  const state = { refused: null };

  async function get() {
    const kept = sessionStorage.getItem(STORE);
    if (kept) return kept;
    if (!entry) throw Object.assign(new Error("this page has no key: open the address the console printed"), { refused: true });
    const r = await fetch("/enter", { method: "POST", headers: { Authorization: `Bearer ${entry}` } });
    if (!r.ok) {
      const why = r.status === 403 && (await r.text()).includes("used already")
        ? "this address was used already: each printed address opens one page (an open page gives another)"
        : `the console refused this address (HTTP ${r.status})`;
      throw Object.assign(new Error(why), { refused: true });
    }
    const key = (await r.json()).key;
    sessionStorage.setItem(STORE, key);
    return key;
  }

  // fetch with this page's key; throws on a refusal (err.refused) or while the console is away
  async function request(path, options = {}) {
    const key = await get();
    const r = await fetch(path, { ...options, headers: { ...(options.headers || {}), Authorization: `Bearer ${key}` } });
    if (r.status === 403) throw Object.assign(new Error("the console refused this page's key"), { refused: true });
    return r;
  }

  // another one-use address, for another tab or another person
  async function invite() { return (await (await request("/invite", { method: "POST" })).json()).address; }

  return { get, request, invite, state };
})();
