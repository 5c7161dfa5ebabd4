// Live page: one depth panel per sensor, fed by the /api/live/ws websocket (binary
// messages: uint32 LE header length, JSON header, JPEG). The page keeps its clock
// offset to the server (min-RTT time pings) to show the end-to-end latency from the
// frame's capture on the sensor to the panel being drawn here.
"use strict";
(() => {
  function el(tag, attrs = {}, ...children) {
    const e = document.createElement(tag);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
    for (const c of children) e.append(c);
    return e;
  }
  const panels = new Map();   // node id -> {fig, canvas, ctx, info, frames, lat: []}
  const clock = { offset: 0, bestRtt: Infinity, samples: [] };
  const stats = { nodes: {}, connected: false, frames: 0 };
  window.liveStats = stats;   // read by the browser tests and handy in the console
  let ws = null, retry = 500, pingTimer = null;

  const nowServer = () => Date.now() / 1000 + clock.offset;
  const median = (a) => { if (!a.length) return null; const s = [...a].sort((x, y) => x - y); return s[s.length >> 1]; };

  function panel(id) {
    let p = panels.get(id);
    if (p) return p;
    const canvas = el("canvas", { width: "256", height: "212", role: "img",
      "aria-label": `Depth image of sensor ${id}` });
    const info = {
      node: el("span", { class: "node" }, id),
      fps: el("span", { class: "num" }, "— fps"),
      lat: el("span", { class: "num" }, "latency —"),
      body: el("span", { class: "nobody" }, "waiting for images…"),
    };
    const fig = el("figure", { class: "panel", "data-node": id }, canvas,
      el("figcaption", {}, info.node, info.fps, info.lat, info.body));
    const box = document.getElementById("panels");
    const after = [...box.children].find((c) => c.dataset.node.localeCompare(id, undefined, { numeric: true }) > 0);
    box.insertBefore(fig, after || null);
    p = { fig, canvas, ctx: canvas.getContext("2d"), info, frames: 0, lat: [], busy: false };
    panels.set(id, p);
    return p;
  }

  async function draw(buf) {
    const dv = new DataView(buf);
    const hlen = dv.getUint32(0, true);
    const h = JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, hlen)));
    const p = panel(h.node);
    const bmp = await createImageBitmap(new Blob([new Uint8Array(buf, 4 + hlen)], { type: "image/jpeg" }));
    if (p.canvas.width !== bmp.width || p.canvas.height !== bmp.height) {
      p.canvas.width = bmp.width; p.canvas.height = bmp.height;
    }
    p.ctx.drawImage(bmp, 0, 0);
    bmp.close();
    p.frames += 1;
    stats.frames += 1;
    p.fig.classList.remove("offline");
    if (h.t_capture !== null) {
      p.lat.push(1000 * (nowServer() - h.t_capture));
      if (p.lat.length > 60) p.lat.shift();
    }
    const lat = median(p.lat);
    p.info.fps.textContent = `${h.fps.toFixed(1)} fps`;
    p.info.lat.textContent = lat === null ? "latency —" : `latency ${lat.toFixed(0)} ms`;
    const tracked = h.body_pixels > 0;
    p.info.body.textContent = tracked ? "body tracked (magenta)" : "no body tracked";
    p.info.body.className = tracked ? "body" : "nobody";
    stats.nodes[h.node] = { frames: p.frames, fps: h.fps, latency_ms: lat, body_pixels: h.body_pixels,
      seq: h.seq };
  }

  function summary() {
    const ids = Object.keys(stats.nodes);
    const lats = ids.map((k) => stats.nodes[k].latency_ms).filter((v) => v !== null);
    const el = document.getElementById("live-summary");
    if (!stats.connected) { el.textContent = "Live stream disconnected; reconnecting…"; return; }
    if (!ids.length) { el.textContent = "Connected; waiting for the first depth images…"; return; }
    const worst = lats.length ? Math.max(...lats) : null;
    el.textContent = `${ids.length} sensor${ids.length > 1 ? "s" : ""} streaming; capture-to-screen latency ` +
      (lats.length ? `median ${median(lats).toFixed(0)} ms, worst sensor ${worst.toFixed(0)} ms` : "measuring…") +
      ` (clock offset to the server measured to ±${(1000 * clock.bestRtt / 2).toFixed(1)} ms).`;
    stats.latency_ms = lats.length ? median(lats) : null;
  }

  function ping() { if (ws && ws.readyState === 1) ws.send(JSON.stringify({ type: "time", echo: Date.now() / 1000 })); }

  function onText(m) {
    if (m.type !== "time") return;
    const now = Date.now() / 1000;
    const rtt = now - m.echo;
    clock.samples.push({ rtt, offset: m.t + rtt / 2 - now });
    if (clock.samples.length > 20) clock.samples.shift();
    const best = clock.samples.reduce((a, b) => (b.rtt < a.rtt ? b : a));
    clock.offset = best.offset; clock.bestRtt = best.rtt;
  }

  function connect() {
    const proto = location.protocol === "https:" ? "wss:" : "ws:";
    ws = new WebSocket(`${proto}//${location.host}/api/live/ws`);
    ws.binaryType = "arraybuffer";
    ws.onopen = () => { stats.connected = true; retry = 500; for (let i = 0; i < 5; i++) setTimeout(ping, 50 * i); summary(); };
    ws.onmessage = (ev) => {
      if (typeof ev.data === "string") { try { onText(JSON.parse(ev.data)); } catch (e) { /* ignore */ } return; }
      draw(ev.data).catch((e) => console.warn("panel not drawn:", e))
        .finally(() => { if (ws && ws.readyState === 1) ws.send('{"type":"ack"}'); });
    };
    ws.onclose = (ev) => {
      stats.connected = false; summary();
      if (ev.code === 4401) { window.location.href = "/index.html"; return; }
      setTimeout(connect, retry); retry = Math.min(retry * 2, 8000);
    };
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
    setInterval(summary, 1000);
    setInterval(nodes, 5000);
    pingTimer = setInterval(ping, 2000);
  }
  init();
})();
