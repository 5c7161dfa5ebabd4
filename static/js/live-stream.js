// Live depth panels: the /api/live/ws stream, shared by the Live page's worker
// (live-worker.js) and, in a browser without OffscreenCanvas, the page itself.
//
// Binary messages: uint32 LE header length, JSON header, JPEG. Each panel is decoded
// and drawn into its node's canvas, then acknowledged with its node (the server keeps at
// most two panels per node in flight and replaces older ones, so a slow page skips
// frames instead of lagging). The page's clock offset to the server comes from min-RTT time pings, so the
// capture time (server clock: the node clock corrected by the server's offset
// estimate) becomes an end-to-end latency on this clock.
//
// Running in a worker keeps the panels flowing while the page's main thread is busy
// (the embedded 3D view renders on the same thread, in software on a machine without
// a GPU).
"use strict";

// eslint-disable-next-line no-unused-vars
function gaitrigLiveStream(opts) {
  // opts.url: websocket URL; opts.canvas(node) → a canvas (HTMLCanvasElement or
  // OffscreenCanvas) or null if not there yet; opts.report(msg): stats / events out.
  // The caption's "body tracked" must describe the picture shown (it followed the
  // statistics, a report later, and said "body tracked" under a picture without one):
  // opts.painted(node, tracked), on the page's thread, is called right after a panel is
  // painted, in the same task (one frame of the screen has both); in a worker,
  // opts.handover(node, bitmap, tracked) gives the page a panel whose tracked state differs
  // from its caption's, for the page to draw over the canvas with its caption in one
  // task; captioned(node, tracked) says the page did, and the worker paints that state's
  // panels from then on (a {type: "painted"} report lets the page lift its copy).
  const clock = { offset: 0, bestRtt: Infinity, samples: [] };
  const nodes = {};   // node → {frames, fps, latency_ms, body_pixels, seq, lat: []}
  const waiting = {}; // node → newest panel bitmap while its canvas is not there yet
  const VISIBLE_BODY = 0.001;  // share of a panel's pixels from which a body is seen
  const captioned = {}, handing = {}, overlaid = {};  // node → caption state, handover out, page copy shown
  let ws = null, retry = 500, frames = 0, dirty = true;
  let openedAt = Infinity;  // this page's clock (s) when the stream last opened
  const STALE_S = 1.0;
  const timing = { decode: [], draw: [] };  // ms, the newest 60 panels
  const keep = (a, v) => { a.push(v); if (a.length > 60) a.shift(); };

  const now = () => Date.now() / 1000;
  const median = (a) => { if (!a.length) return null; const s = [...a].sort((x, y) => x - y); return s[s.length >> 1]; };

  function paint(node, bmp) {
    const c = opts.canvas(node);
    if (!c) {
      if (waiting[node]) waiting[node].close();
      waiting[node] = bmp;
      return;
    }
    if (c.width !== bmp.width || c.height !== bmp.height) { c.width = bmp.width; c.height = bmp.height; }
    c.getContext("2d").drawImage(bmp, 0, 0);
    bmp.close();
  }

  function header(buf) {
    const hlen = new DataView(buf).getUint32(0, true);
    return [hlen, JSON.parse(new TextDecoder().decode(new Uint8Array(buf, 4, hlen)))];
  }

  async function draw(buf, hlen, h) {
    const t0 = performance.now();
    const bmp = await createImageBitmap(new Blob([new Uint8Array(buf, 4 + hlen)], { type: "image/jpeg" }));
    const t1 = performance.now();
    // a body of a few pixels (far off, at the edge) is no body to see in the picture: the
    // caption said "body tracked" over a picture without one
    const tracked = h.body_pixels > VISIBLE_BODY * (h.width * h.height || 0);
    if (opts.handover && tracked !== captioned[h.node]) {
      // the caption changes with this picture: the page shows both (one at a time: a
      // newer panel of either state waits for the answer, dropped)
      if (!handing[h.node]) { handing[h.node] = true; opts.handover(h.node, bmp, tracked); } else bmp.close();
    } else {
      paint(h.node, bmp);
      if (opts.painted) opts.painted(h.node, tracked);
      if (overlaid[h.node]) { overlaid[h.node] = false; opts.report({ type: "painted", node: h.node, tracked }); }
    }
    keep(timing.decode, t1 - t0);
    keep(timing.draw, performance.now() - t1);
    const n = nodes[h.node] || (nodes[h.node] = { frames: 0, lat: [] });
    n.frames += 1;
    frames += 1;
    // A panel captured before this page began to look is the server's last one from an
    // earlier watch (the nodes stop sending pictures while nobody watches): drawn, but no
    // latency ("median 22904 ms" on opening the page, until fresh pictures came).
    const stale = h.t_capture !== null && h.t_capture < openedAt + clock.offset - STALE_S;
    if (h.t_capture !== null && clock.bestRtt < Infinity && !stale) {
      n.lat.push(1000 * (now() + clock.offset - h.t_capture));
      if (n.lat.length > 60) n.lat.shift();
    }
    Object.assign(n, { fps: h.fps, latency_ms: median(n.lat), body_pixels: h.body_pixels, seq: h.seq });
    dirty = true;
  }

  function ping() { if (ws && ws.readyState === 1) ws.send(JSON.stringify({ type: "time", echo: now() })); }

  function onText(m) {
    if (m.type !== "time") return;
    const t = now(), rtt = t - m.echo;
    clock.samples.push({ rtt, offset: m.t + rtt / 2 - t });
    if (clock.samples.length > 20) clock.samples.shift();
    const best = clock.samples.reduce((a, b) => (b.rtt < a.rtt ? b : a));
    clock.offset = best.offset; clock.bestRtt = best.rtt;
  }

  function report(force) {
    if (!dirty && !force) return;
    dirty = false;
    const out = {};
    for (const [k, v] of Object.entries(nodes)) {
      out[k] = { frames: v.frames, fps: v.fps, latency_ms: v.latency_ms, body_pixels: v.body_pixels, seq: v.seq };
    }
    opts.report({ type: "stats", connected: !!ws && ws.readyState === 1, frames, nodes: out,
      clock_rtt_ms: clock.bestRtt < Infinity ? 1000 * clock.bestRtt : null,
      decode_ms: median(timing.decode), draw_ms: median(timing.draw) });
  }

  function connect() {
    ws = new WebSocket(opts.url);
    ws.binaryType = "arraybuffer";
    ws.onopen = () => { retry = 500; openedAt = now(); for (let i = 0; i < 5; i++) setTimeout(ping, 50 * i); report(true); };
    ws.onmessage = (ev) => {
      if (typeof ev.data === "string") { try { onText(JSON.parse(ev.data)); } catch (e) { /* not ours */ } return; }
      let hlen, h;
      try { [hlen, h] = header(ev.data); } catch (e) { console.warn("bad panel:", e); return; }
      const ack = JSON.stringify({ type: "ack", node: h.node });
      draw(ev.data, hlen, h).catch((e) => console.warn("panel not drawn:", e))
        .finally(() => { if (ws && ws.readyState === 1) ws.send(ack); });
    };
    ws.onclose = (ev) => {
      report(true);
      if (ev.code === 4401) { opts.report({ type: "unauthorized" }); return; }
      setTimeout(connect, retry); retry = Math.min(retry * 2, 8000);
    };
  }

  connect();
  setInterval(ping, 2000);
  setInterval(report, 200);
  return {
    // a canvas for ``node`` became available: draw what waited for it
    canvasReady(node) { const b = waiting[node]; if (b) { delete waiting[node]; paint(node, b); } },
    // the page shows a panel of this state with its caption (after opts.handover)
    captioned(node, tracked) { captioned[node] = tracked; handing[node] = false; overlaid[node] = true; },
  };
}
