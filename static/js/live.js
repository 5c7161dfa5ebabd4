// Live page: one depth panel per sensor, fed by the /api/live/ws websocket (see
// live-stream.js: JPEG panels, credit flow control, end-to-end latency from the frame's
// capture on the sensor to the panel drawn here). A worker receives and draws the panels
// into OffscreenCanvases, so they keep their rate while the embedded 3D view keeps the
// page's own thread busy; this script builds the panels and shows the statistics.
"use strict";
(() => {
  const el = gaitrig.el;
  const panels = new Map();   // node id -> {fig, canvas, info}
  const stats = { nodes: {}, connected: false, frames: 0, latency_ms: null, mode: null };
  window.liveStats = stats;   // read by the browser tests and handy in the console
  let stream = null, worker = null, clockRtt = null;

  const median = (a) => { if (!a.length) return null; const s = [...a].sort((x, y) => x - y); return s[s.length >> 1]; };
  const offscreen = typeof Worker !== "undefined" && typeof OffscreenCanvas !== "undefined" &&
    "transferControlToOffscreen" in HTMLCanvasElement.prototype;

  function panel(id) {
    let p = panels.get(id);
    if (p) return p;
    const canvas = el("canvas", { width: "256", height: "212", role: "img",
      "aria-label": `Depth image of sensor ${id}` });
    // a panel whose caption changes, drawn here with it in one task over the worker's
    // canvas until the worker paints that state too (live-stream.js)
    const cover = el("canvas", { width: "256", height: "212", class: "cover", "aria-hidden": "true" });
    cover.hidden = true;
    const info = {
      node: el("span", { class: "node" }, id),
      fps: el("span", { class: "num" }, "— fps"),
      lat: el("span", { class: "num" }, "latency —"),
      body: el("span", { class: "nobody" }, "waiting for images…"),
    };
    const fig = el("figure", { class: "panel", "data-node": id }, el("div", { class: "frame" }, canvas, cover),
      el("figcaption", {}, info.node, info.fps, info.lat, info.body));
    const box = document.getElementById("panels");
    const after = [...box.children].find((c) => c.dataset.node.localeCompare(id, undefined, { numeric: true }) > 0);
    box.insertBefore(fig, after || null);
    p = { fig, canvas, cover, info, tracked: undefined };
    panels.set(id, p);
    if (worker) {  // the worker draws into it from now on
      const off = canvas.transferControlToOffscreen();
      worker.postMessage({ type: "canvas", node: id, canvas: off }, [off]);
    } else if (stream) stream.canvasReady(id);
    return p;
  }

  // "body tracked" says what the picture shown has: set with the picture (caption()),
  // not from the statistics, which came a report later
  function caption(p, tracked) {
    p.tracked = tracked;
    p.info.body.textContent = tracked ? "body tracked (magenta)" : "no body tracked";
    p.info.body.className = tracked ? "body" : "nobody";
  }
  function handover(m) {
    const p = panel(m.node), c = p.cover;
    if (c.width !== m.bitmap.width || c.height !== m.bitmap.height) { c.width = m.bitmap.width; c.height = m.bitmap.height; }
    c.getContext("2d").drawImage(m.bitmap, 0, 0);
    m.bitmap.close();
    c.hidden = false;
    caption(p, m.tracked);
    worker.postMessage({ type: "captioned", node: m.node, tracked: m.tracked });
  }

  // The rest of the captions follow the stream's statistics (a few times a second).
  function onStats(m) {
    if (m.type === "unauthorized") { gaitrig.toLogin(); return; }
    if (m.type === "handover") { handover(m); return; }
    // the worker's canvas shows the caption's state now: the copy over it goes
    if (m.type === "painted") { const p = panel(m.node); if (p.tracked === m.tracked) p.cover.hidden = true; return; }
    if (m.type !== "stats") return;
    stats.connected = m.connected;
    stats.frames = m.frames;
    clockRtt = m.clock_rtt_ms;
    stats.decode_ms = m.decode_ms;
    stats.draw_ms = m.draw_ms;
    for (const [id, n] of Object.entries(m.nodes)) {
      const p = panel(id);
      const old = stats.nodes[id];
      stats.nodes[id] = n;
      if (old && old.frames === n.frames) continue;
      p.fig.classList.remove("offline");
      p.info.fps.textContent = `${(n.fps || 0).toFixed(1)} fps`;
      p.info.lat.textContent = n.latency_ms === null ? "latency —" : `latency ${n.latency_ms.toFixed(0)} ms`;
      if (p.tracked !== undefined) caption(p, p.tracked);  // (back from "sensor offline")
    }
    summary();
  }

  function summary() {
    const ids = Object.keys(stats.nodes);
    const lats = ids.map((k) => stats.nodes[k].latency_ms).filter((v) => v !== null);
    const el = document.getElementById("live-summary");
    stats.latency_ms = lats.length ? median(lats) : null;
    // a screen reader hears the stream's state when it changes, not every new latency
    const state = !stats.connected ? "Live stream disconnected; reconnecting…"
      : !ids.length ? "Connected; waiting for the first depth images…"
      : `${gaitrig.plural(ids.length, "sensor")} streaming.`;
    const live = document.getElementById("live-state");
    if (live && live.textContent !== state) live.textContent = state;
    if (!stats.connected || !ids.length) { el.textContent = state; return; }
    const worst = lats.length ? Math.max(...lats) : null;
    el.textContent = `${ids.length} sensor${ids.length > 1 ? "s" : ""} streaming; capture-to-screen latency ` +
      (lats.length ? `median ${median(lats).toFixed(0)} ms, worst sensor ${worst.toFixed(0)} ms` : "measuring…") +
      // (a loopback round trip printed "±0.0 ms", as if exact)
      (clockRtt === null ? "" : ` (clock offset to the server measured to ${clockRtt / 2 < 0.05 ? "better than ±0.1" : "±" + (clockRtt / 2).toFixed(1)} ms).`);
  }

  function connect() {
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    const url = `${proto}//${location.host}/api/live/ws`;
    if (offscreen) {
      worker = new Worker("/js/live-worker.js");
      worker.onmessage = (ev) => onStats(ev.data);
      worker.onerror = (ev) => console.warn("live worker:", ev.message);
      for (const [id, p] of panels) {
        const off = p.canvas.transferControlToOffscreen();
        worker.postMessage({ type: "canvas", node: id, canvas: off }, [off]);
      }
      worker.postMessage({ type: "start", url });
      stats.mode = "worker";
    } else {  // older browsers: the same code on the page's own thread
      // eslint-disable-next-line no-undef
      stream = gaitrigLiveStream({ url, canvas: (id) => (panels.get(id) || {}).canvas || null,
        report: onStats, painted: (id, tracked) => caption(panel(id), tracked) });
      stats.mode = "page";
    }
  }

  async function nodes() {
    try {
      for (const n of await gaitrig.api("/api/nodes")) {
        const p = panel(n.id);
        p.fig.classList.toggle("offline", !n.connected);
        if (!n.connected) { p.info.body.textContent = "sensor offline"; p.info.body.className = "nobody"; }
      }
    } catch (e) { document.getElementById("live-summary").textContent = "Cannot list the sensors: " + e.message; }
  }

  async function init() {
    const sys = await gaitrig.api("/api/system");
    const frame = document.getElementById("viewer"), open = document.getElementById("viewer-open");
    if (sys.viewer_url) { frame.src = sys.viewer_url; open.href = sys.viewer_url; }
    else { frame.replaceWith(el("p", { class: "note" }, "The 3D view is disabled on this server (started with --no-viewer).")); open.remove(); }
    await nodes();
    connect();
    gaitrig.poll(nodes, 5000);  // (not while the tab is hidden)
  }
  init();
})();
