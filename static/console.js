// gaitrig console: plain JS, no build step. The session cookie set by /api/auth/login
// authenticates every fetch; a 401 sends the user back to the login page.
"use strict";
const gaitrig = (() => {
  // Several requests of a page can fail with 401 at once; navigate to the login page
  // once, not again while it is loading (a second navigation would reload it under the
  // user's typing). Every page script that meets a 401 (its own fetch, a websocket
  // closed as unauthorised) goes through toLogin().
  let leaving = false;
  // The login brings the user back to the page (and its #subject=…) she was on: a session
  // that ran out sent her to the Rig page, to find her subject again.
  function toLogin() {
    if (leaving) return;
    leaving = true;
    const here = location.pathname + location.search + location.hash;
    window.location.href = location.pathname === "/index.html" ? "/index.html"
      : "/index.html?next=" + encodeURIComponent(here);
  }
  // Only a page of this console: a ?next= pointing at another site is ignored.
  function nextPage() {
    const next = new URLSearchParams(location.search).get("next") || "";
    return /^\/(?![/\\])[\w./-]*\.html([?#].*)?$/.test(next) && !next.startsWith("/index.html") ? next : "/rig.html";
  }
  // (a failed fetch said only "Failed to fetch")
  const UNREACHABLE = "no answer from the server: check that it is running and that this computer is on the lab's network";
  async function api(path, options = {}) {
    let r;
    try {
      r = await fetch(path, { credentials: "same-origin", ...options,
        headers: { "Content-Type": "application/json", ...(options.headers || {}) } });
    } catch (e) { throw new Error(UNREACHABLE); }
    if (r.status === 401) { toLogin(); throw new Error("not logged in"); }
    if (!r.ok) {
      let d = r.statusText; try { d = (await r.json()).detail; } catch (e) {}
      const err = new Error(d); err.status = r.status; throw err;  // status: retry or not
    }
    return r.status === 204 ? null : r.json();
  }
  // An element with attributes (``on<event>`` ones become listeners: the CSP allows no
  // inline handlers) and children (null/undefined ones left out). The pages use this one.
  function el(tag, attrs = {}, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs)) {
      if (k.startsWith("on")) e.addEventListener(k.slice(2), v); else e.setAttribute(k, v);
    }
    for (const c of children) if (c !== null && c !== undefined) e.append(c);
    return e;
  }
  // The chosen entry's text, whole, under a list too narrow to show it (a long label or
  // code, a phone or a zoomed window: 320 px shows "walk 3 self-selected speed — L"), in
  // the list's `#<list>-whole` paragraph, hidden while the list shows it whole. For the
  // lists `ids` (the Reports page's subject, session and recording, the Record page's
  // subject and session); a page calls it when a list changes and on resize.
  const measure = document.createElement("canvas").getContext("2d");
  function showWhole(ids) {
    for (const id of ids) {
      const sel = document.getElementById(id), p = document.getElementById(id + "-whole");
      if (!sel || !p) continue;
      const text = sel.value && sel.selectedOptions.length ? sel.selectedOptions[0].textContent : "";
      let cut = false;
      if (text && sel.clientWidth) {
        // A list is as wide as its widest entry unless its box holds it narrower: the
        // room for the text is the widest entry less what the box takes off (a list out
        // of the flow for a moment shows its own width). Not a guess of the arrow's width:
        // a guess wrote an entry shown whole under its list again.
        measure.font = getComputedStyle(sel).font;
        const shown = sel.getBoundingClientRect().width;
        const style = sel.style.cssText;  // (CSSOM: the console's CSP refuses style attributes)
        sel.style.cssText += ";position:absolute;width:auto;max-width:none";
        const own = sel.getBoundingClientRect().width;
        sel.style.cssText = style;
        const widest = Math.max(...[...sel.options].map((o) => measure.measureText(o.textContent).width));
        cut = measure.measureText(text).width > widest - Math.max(0, own - shown) + 0.5;
      }
      p.hidden = !cut;
      p.textContent = cut ? text : "";
    }
  }
  // A page of a list with how many match in all (the X-Total-Count header). With `body`,
  // a POST: a subject code searched for goes in the body, never in a URL (access logs).
  async function listPage(path, body) {
    const opts = body === undefined ? {} : { method: "POST", body: JSON.stringify(body) };
    const r = await fetch(path, { credentials: "same-origin", ...opts, headers: { "Content-Type": "application/json" } });
    if (r.status === 401) { toLogin(); throw new Error("not logged in"); }
    if (!r.ok) { let d = r.statusText; try { d = (await r.json()).detail; } catch (e) { /* not JSON */ } throw new Error(d); }
    const items = await r.json();
    return { items, total: Number(r.headers.get("X-Total-Count") ?? items.length) };
  }
  // A focused button disabled while its action runs drops the keyboard focus to the page
  // (Tab then starts over from the top); release() re-enables it and gives the focus back
  // unless the user has put it somewhere else meanwhile.
  function release(btn) {
    btn.disabled = false;
    if (!document.activeElement || document.activeElement === document.body) btn.focus({ preventScroll: true });
  }
  // A session's day ("2026-11-24") as the user writes dates ("24 Nov 2026", "Nov 24, 2026");
  // the month spelled out, so 03/04 cannot be read as either March or April.
  // A Date is written as its day on the user's calendar.
  const DAY = { day: "numeric", month: "short", year: "numeric" };
  function day(iso) {
    // local midnight: the same calendar day everywhere
    const d = iso instanceof Date ? iso : new Date(`${iso}T00:00:00`);
    return Number.isNaN(d.getTime()) ? String(iso) : d.toLocaleDateString(undefined, DAY);
  }
  // A moment (a Date, or seconds since the epoch as the API's t_start and created) the same
  // way, with the time on the user's clock: "28 Nov 2026, 10:07:14" / "Nov 28, 2026,
  // 10:07:14 AM" (the wizard wrote "11/28/2026, 10:07:14 AM" beside "Nov 28, 2026").
  // seconds: false drops them (a log's minute is enough).
  function dateTime(t, { seconds = true } = {}) {
    const d = t instanceof Date ? t : new Date(t * 1000);
    return d.toLocaleString(undefined, { ...DAY, hour: "numeric", minute: "2-digit", ...(seconds ? { second: "2-digit" } : {}) });
  }
  // A moment of today by its time alone ("1:14:10 PM"), another day's with its date: a
  // check or warning from yesterday read "at 10:02:11 AM" as if it were this morning's.
  function moment(t) {
    const d = t instanceof Date ? t : new Date(t * 1000);
    return d.toDateString() === new Date().toDateString() ? d.toLocaleTimeString() : dateTime(d);
  }
  function fmt(v, digits, unit) { return v === null || v === undefined ? "—" : v.toFixed(digits) + unit; }
  // A count with its noun in the right number: plural(1, "recording") is "1 recording",
  // plural(2, "copy", "copies") "2 copies" (the console wrote "1 recording(s)").
  function plural(n, one, many = one + "s") { return `${n} ${n === 1 ? one : many}`; }
  // A time the API sent (ISO 8601 with an offset) as a Date. The server keeps UTC; a value
  // without an offset (an older server) is read as UTC too, not as the browser's local
  // time (which would put it hours off). Shown with toLocale…String: the user's own zone.
  function when(iso) {
    return new Date(/(?:[zZ]|[+-]\d\d:?\d\d)$/.test(iso) ? iso : iso + "Z");
  }

  // Polling that stops while the page is hidden (a background tab, a minimised window):
  // a console left open in a few tabs asked the server several times a second for pages
  // nobody looked at. poll(fn, ms) calls fn every ms while document.hidden is false and
  // once at once when the page is shown again (what it showed is stale by then); stop()
  // ends it. Overlapping calls are the caller's affair, as with setInterval (the pages
  // drop stale answers with newest()/latest()).
  function poll(fn, ms) {
    let timer = null, stopped = false;
    const halt = () => { if (timer !== null) { clearInterval(timer); timer = null; } };
    const start = () => { if (timer === null && !stopped) timer = setInterval(fn, ms); };
    const seen = () => {
      if (document.hidden) { halt(); return; }
      if (timer === null && !stopped) { fn(); start(); }
    };
    document.addEventListener("visibilitychange", seen);
    if (!document.hidden) start();
    return { stop() { stopped = true; halt(); document.removeEventListener("visibilitychange", seen); } };
  }
  // The step of a polling chain (setTimeout(next, ms) in a loop): a promise that settles
  // ms later, or, when the page is hidden then, as soon as it is shown again.
  function wait(ms) {
    return new Promise((resolve) => setTimeout(() => {
      if (!document.hidden) { resolve(); return; }
      const back = () => {
        if (document.hidden) return;
        document.removeEventListener("visibilitychange", back);
        resolve();
      };
      document.addEventListener("visibilitychange", back);
    }, ms));
  }

  function loginPage() {
    const form = document.getElementById("login-form");
    form.addEventListener("submit", async (ev) => {
      ev.preventDefault();
      const msg = document.getElementById("login-error");
      msg.textContent = "";
      try {
        const r = await fetch("/api/auth/login", { method: "POST", credentials: "same-origin",
          headers: { "Content-Type": "application/json" },
          body: JSON.stringify({ username: form.username.value, password: form.password.value }) });
        if (r.status === 401) { msg.textContent = "Wrong user name or password."; return; }
        if (!r.ok) {  // a pause after repeated wrong passwords (429) says how long: show that
          let d = r.statusText; try { d = (await r.json()).detail || d; } catch (e) {}
          msg.textContent = `Not logged in: ${d}`; return;
        }
        window.location.href = nextPage();
      } catch (e) { msg.textContent = `Not logged in: ${UNREACHABLE}.`; }
    });
  }

  function clockCell(n) {
    if (!n.connected) return "—";
    if (n.clock_offset_ms === null) return "measuring…";
    const text = `${n.clock_offset_ms.toFixed(2)} ms ± ${n.clock_uncertainty_ms.toFixed(2)} ms`;
    // the server's warning (it clears below 3/4 of the limit: no flicker at the limit)
    return n.clock_warning ? el("span", { class: "warn" }, text + " (too uncertain)") : text;
  }

  // Free space, and what the node's own recordings hold: parts the server has not verified
  // yet are the only copies (the node never deletes them); verified ones are purged by its
  // retention policy.
  function diskCell(n) {
    const gb = (b) => (b / 2 ** 30).toFixed(1) + " GB";
    const free = n.disk_free_bytes === null ? "—" : gb(n.disk_free_bytes) + " free";
    const s = n.storage;
    if (!s || !s.held_parts) return free;
    const parts = `${plural(s.held_parts, "recording part")} (${gb(s.held_bytes)})`;
    const state = s.unverified_parts
      ? el("span", { class: "warn" }, `${s.unverified_parts} not yet on the server`)
      : "all verified on the server";
    const keep = s.keep_verified_days > 0 ? `${s.keep_verified_days} days after verification` : "as soon as verified";
    return el("span", { class: "disk", title: `Verified copies are deleted ${keep}, or earlier when free space falls below ${gb(s.min_free_bytes)}; unverified parts are never deleted.` },
      `${free} · ${parts}, `, state);
  }

  // The lens the node announced (the live 3D view draws its depth through it until a
  // calibration recorded one), in plain words: where from and its first coefficients.
  function lensText(lens) {
    const d = lens && lens.depth_dist;
    if (!d) return "Lens: none reported (drawn as a pinhole camera)";
    if (!d.length) return `Lens: no distortion (${lens.source})`;
    const coef = ["k1", "k2"].map((k, i) => `${k} ${d[i].toFixed(3)}`).join(", ");
    return `Lens: ${lens.source} (${coef}, …)`;
  }

  function row(n) {
    const status = n.connected ? el("span", { class: "ok" }, "online") : el("span", { class: "off" }, "offline");
    const notes = el("ul", { class: "warnings" });
    for (const w of n.warnings) notes.append(el("li", {}, w));
    // what the sensor itself warned about after it connected (body tracking stopped, its
    // clock, frames late): the newest three, with when it last did
    for (const w of (n.node_warnings || []).slice(0, 3)) {
      const time = moment(w.at);
      notes.append(el("li", { class: "node-warning" }, `The sensor warned at ${time}: ${w.text}` +
        (w.repeats > 1 ? ` (${w.repeats} times)` : "")));
    }
    const free = diskCell(n);
    return el("tr", { "data-node": n.id },
      el("th", { scope: "row" }, n.id, el("div", { class: "lens" }, lensText(n.lens))),
      el("td", {}, status),
      el("td", { class: "num" }, n.connected ? fmt(n.fps, 1, " fps") : "—"),
      el("td", { class: "num" }, String(n.dropped_frames)),
      el("td", { class: "num" }, clockCell(n)),
      el("td", { class: "num" }, free), el("td", {}, notes.children.length ? notes : "OK"));
  }

  // Requests that poll a state overlap on a slow server and can be answered out of
  // order: newest() drops an answer older than one already shown, or issued before the
  // user's last action (which then changed the state it describes).
  function newest() {
    let issued = 0, shown = 0;
    return {
      ask() { return ++issued; },
      fresh(n) { if (n < shown) return false; shown = n; return true; },
      acted() { shown = ++issued; },
    };
  }

  // latest(): only the answer to the request asked last is drawn; acted() makes every
  // request still out stale (the user's action changed what they describe).
  function latest() {
    let asked = 0;
    return { ask() { return ++asked; }, current(n) { return n === asked; }, acted() { asked++; } };
  }

  // A quiet reminder for administrators (only they get last_backup_at): no backup for
  // 7 days, or none ever (gaitrig backup, docs/backup.md).
  function backupNotice(sys) {
    if (!("last_backup_at" in sys) || document.getElementById("backup-notice")) return;
    const at = sys.last_backup_at ? when(sys.last_backup_at).getTime() : NaN;
    if (at && Date.now() - at < 7 * 86400e3) return;
    const text = sys.last_backup_at
      ? `No backup of this server since ${day(new Date(at))}.`
      : "This server has never been backed up.";
    // (a clinician logged in as administrator read a command and a file they could not
    // open: who does it, and the guide's words on it, are said too)
    document.getElementById("summary").before(el("p", { id: "backup-notice", role: "status" },
      text + " Ask whoever looks after the server to run gaitrig backup there (docs/backup.md): ",
      el("a", { href: "/help.html#backups" }, "why backups matter")));
  }

  async function rigPage() {
    const sys = await api("/api/system");
    document.getElementById("token-warning").hidden = !sys.node_token_is_default;
    backupNotice(sys);
    const nodeSeq = newest();
    // #summary is a live region: the same text written again every second was read out
    // again by screen readers; only a change is written
    const say = (text) => {
      const s = document.getElementById("summary");
      if (s.textContent !== text) s.textContent = text;
    };
    async function refresh() {
      const n = nodeSeq.ask();
      try {
        const nodes = await api("/api/nodes");
        if (!nodeSeq.fresh(n)) return;
        const body = document.getElementById("nodes");
        body.replaceChildren(...nodes.map((n) => row(n)));
        const online = nodes.filter((n) => n.connected).length;
        const clockBad = nodes.filter((n) => n.connected && n.clock_warning).length;
        say(`${online} of ${nodes.length} sensors online.` +
          (clockBad ? ` ${clockBad} with a clock uncertainty above ${sys.clock_warn_ms} ms.` : ""));
      } catch (e) { say("The sensor list is not up to date: " + e.message); }
    }
    const recBtn = document.getElementById("record");
    let active = null;
    recBtn.addEventListener("click", async () => {
      const status = document.getElementById("record-status");
      recBtn.disabled = true;
      try {
        if (active) { await api(`/api/recordings/${active}/stop`, { method: "POST" }); status.textContent = "Stopped."; }
        else { const r = await api("/api/recordings", { method: "POST", body: "{}" }); status.textContent = `Recording ${r.id}…`; }
      } catch (e) { status.textContent = e.message; }
      // a list asked for before the start/stop would show the old state (and make the
      // button start where it should stop)
      recSeq.acted();
      await refreshRecordings();
      release(recBtn);
    });
    const STATES = { recording: "recording", stopping: "stopping…", on_nodes: "complete on the sensors",
      incomplete: "incomplete", on_node: "on the sensor", pending: "starting",
      transferring: "copying to the server…", complete: "complete on the server" };
    async function transfer(id) {
      const status = document.getElementById("record-status");
      try { await api(`/api/recordings/${id}/transfer`, { method: "POST", body: "{}" }); status.textContent = `Copying ${id} to the server…`; }
      catch (e) { status.textContent = e.message; }
      recSeq.acted();
      await refreshRecordings();
    }
    const recSeq = newest();
    let drawn = "";
    async function refreshRecordings() {
      const n = recSeq.ask();
      try {
        const recs = await api("/api/recordings");
        if (!recSeq.fresh(n)) return;
        active = (recs.find((r) => r.state === "recording") || {}).id || null;
        recBtn.textContent = active ? "Stop recording" : "Start recording";
        // Redrawn only when something changed: replacing the table every second would
        // take a "Copy to server" button from under the pointer and the keyboard focus.
        const shown = JSON.stringify(recs.slice(0, 10));
        if (shown === drawn) return;
        drawn = shown;
        if (!recs.length) {  // (an empty table under its headings looked like a page still loading)
          document.getElementById("recordings").replaceChildren(el("tr", {}, el("td", { colspan: "5" },
            "No recordings yet: record a subject's walk on the Record page.")));
          return;
        }
        document.getElementById("recordings").replaceChildren(...recs.slice(0, 10).map((r) => {
          const parts = el("ul", { class: "parts" });
          for (const p of r.parts) {
            parts.append(el("li", { class: p.state === "incomplete" ? "warn" : "" },
              `${p.node_id}: ${STATES[p.state] || p.state}, ${plural(p.n_frames, "frame")}` +
              (p.state === "transferring" && p.transfer_progress !== null ? ` (${Math.round(p.transfer_progress * 100)} %)` : "") +
              (p.on_server && p.state === "incomplete" ? " (copy on the server)" : "") +
              (p.reason ? ` — ${p.reason}` : "")));
          }
          const len = r.t_stop ? (r.t_stop - r.t_start).toFixed(1) + " s" : "running";
          const state = el("td", { class: "state" }, STATES[r.state] || r.state);
          if (r.parts.some((p) => (p.state === "on_node" || p.state === "incomplete") && !p.on_server && p.n_frames)) {
            const b = el("button", { class: "secondary transfer" }, "Copy to server");
            b.addEventListener("click", () => transfer(r.id));
            state.append(" ", b);
          }
          return el("tr", { "data-recording": r.id }, el("th", { scope: "row" }, r.id),
            // the user's own clock and date format (was UTC, an hour or more off the wall clock)
            el("td", {}, dateTime(r.t_start)),
            el("td", { class: "num" }, len), state, el("td", {}, parts));
        }));
      } catch (e) { /* shown by the node refresh */ }
    }
    await refresh();
    await refreshRecordings();
    poll(refresh, 1000);
    poll(refreshRecordings, 1000);
  }
  return { api, el, listPage, showWhole, toLogin, newest, latest, release, day, dateTime, moment, plural, when, poll, wait,
    loginPage, rigPage };
})();

// The browser refuses a field that does not match its pattern with "Please match the
// requested format.", which does not say which format: a field with a pattern says its
// title (written as an instruction) instead. Cleared as soon as the user types again.
document.addEventListener("invalid", (ev) => {
  const f = ev.target;
  if (f.validity && f.validity.patternMismatch && f.title) f.setCustomValidity(f.title);
}, true);
document.addEventListener("input", (ev) => {
  if (ev.target.setCustomValidity) ev.target.setCustomValidity("");
}, true);

// Escape closes an open confirmation (the Subjects page's "Delete this subject", an unfiled
// recording's "Delete…") and gives the focus back to the summary that opened it, as a
// dialog does.
document.addEventListener("keydown", (ev) => {
  if (ev.key !== "Escape" || !(ev.target instanceof Element)) return;
  const zone = ev.target.closest("details.danger-zone[open]");
  if (!zone) return;
  zone.open = false;
  zone.querySelector("summary").focus();
});
