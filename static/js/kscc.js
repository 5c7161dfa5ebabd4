// KSCC page: choose two skeleton sources, calibrate both (countdown, stillness bar,
// restart messages), draw both users in the universal frame, plot their difference,
// share a sensor with another site, show the active-area trapezoids.
"use strict";
(() => {
  const api = gaitrig.api;
  const $ = (id) => document.getElementById(id);
  const el = gaitrig.el;
  const cm = (m) => (m === null || m === undefined ? "—" : (m * 100).toFixed(0) + " cm");
  const COLORS = { a: "#0b5cad", b: "#cf222e" };
  const STATES = { waiting: "Waiting", collecting: "Collecting still frames", moved: "Moved — restarted", done: "Done" };
  // `generation` changes whenever polling starts or stops: a poll answered after Stop
  // would otherwise draw the stopped session again, and nothing would redraw it.
  // `shown` drops a poll asked before the user's Start/Restart (or before a newer poll
  // already drawn) that a loaded server answers late: it would show the old state.
  let polling = false, last = null, generation = 0;
  const shown = gaitrig.newest();

  // ----------------------------------------------------------------- sources
  for (const side of ["a", "b"]) {
    for (const r of document.querySelectorAll(`input[name=kind-${side}]`)) {
      r.addEventListener("change", () => {
        const remote = document.querySelector(`input[name=kind-${side}]:checked`).value === "remote";
        const fs = document.querySelector(`fieldset[data-side=${side}]`);
        fs.querySelector(".remote-fields").hidden = !remote;
        fs.querySelector(".node-fields").hidden = remote;
      });
    }
  }
  let sourcesShown = "";
  async function loadSources() {
    const nodes = await api("/api/kscc/sources");
    // polled every 5 s: replacing the options of an unchanged list would close a list the
    // user has open
    const key = JSON.stringify(nodes.map((n) => [n.node_id, n.connected, n.model]));
    if (key === sourcesShown) return;
    sourcesShown = key;
    for (const [id, pick] of [["node-a", 0], ["node-b", 1], ["share-node", 0]]) {
      const sel = $(id), prev = sel.value;
      sel.replaceChildren(...nodes.map((n) => { const o = el("option", {}, `${n.node_id}${n.connected ? "" : " (offline)"} — ${n.model}`); o.value = n.node_id; return o; }));
      if (!nodes.length) sel.append(el("option", {}, "no sensor connected"));
      sel.value = prev || (nodes[Math.min(pick, nodes.length - 1)] || {}).node_id || "";
    }
  }
  function source(side) {
    const kind = document.querySelector(`input[name=kind-${side}]:checked`).value;
    if (kind === "node") return { kind, node_id: $(`node-${side}`).value };
    return { kind, node_id: $(`rnode-${side}`).value.trim(), url: $(`url-${side}`).value.trim(), token: $(`token-${side}`).value };
  }

  $("session-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    $("error").textContent = "";
    try {
      const s = await api("/api/kscc/session", { method: "POST", body: JSON.stringify({
        a: source("a"), b: source("b"), countdown_s: Number($("countdown").value), by_role: $("by-role").checked }) });
      shown.acted(); render(s); startPolling();
    } catch (e) { $("error").textContent = e.message; }
  });
  // a restart answered after Stop must not draw the stopped session again (as in poll())
  async function restart(side) {
    const asked = generation;
    try {
      const s = await api("/api/kscc/session/restart", { method: "POST", body: JSON.stringify({ side }) });
      if (asked === generation) { shown.acted(); render(s); }
    } catch (e) { if (asked === generation) $("error").textContent = e.message; }
  }
  $("restart").addEventListener("click", () => restart("both"));
  for (const b of document.querySelectorAll("button.recal")) b.addEventListener("click", () => restart(b.dataset.side));
  $("stop").addEventListener("click", async () => {
    stopPolling();
    await api("/api/kscc/session", { method: "DELETE" }).catch(() => {});
    render(null);
  });

  function setRunning(on) {
    for (const b of [$("restart"), $("stop"), ...document.querySelectorAll("button.recal")]) b.disabled = !on;
  }
  // One chain of polls, the next asked 300 ms after the last answer: a fixed interval
  // piled requests up on a loaded server (each slower than 300 ms), answered out of order.
  function startPolling() {
    if (!polling) { polling = true; const mine = ++generation; gaitrig.wait(300).then(() => poll(mine)); }
    setRunning(true);
  }
  function stopPolling() { polling = false; generation++; setRunning(false); }
  async function poll(mine) {
    if (mine !== generation) return;
    const n = shown.ask();
    try {
      const s = await api("/api/kscc/session");
      if (mine !== generation) return;
      if (s.running) { if (shown.fresh(n)) render(s); }
      // (a stale "no session", asked before the user's Start, must not stop the new one)
      else if (shown.fresh(n)) { stopPolling(); render(null); return; }
    } catch (e) {
      if (mine !== generation) return;  // else a failed poll is asked again
    }
    await gaitrig.wait(300);  // (not while the page is hidden; at once when it is shown)
    poll(mine);
  }

  // ------------------------------------------------------------------ render
  function renderSide(box, s) {
    const q = (c) => box.querySelector(c);
    // .message and .countdown are live regions, redrawn many times a second: only a
    // change is written (the same words written again are read out again)
    const put = (c, text) => { if (q(c).textContent !== text) q(c).textContent = text; };
    if (!s) { put(".message", "Not started."); put(".countdown", ""); q("progress").value = 0;
      q(".state").textContent = ""; q(".count").textContent = ""; q(".cal").textContent = ""; q(".src").textContent = ""; return; }
    q(".src").textContent = "— " + s.source + (s.kind === "remote" ? ` (link: ${s.link})` : "");
    put(".countdown", s.countdown_s > 0 ? Math.ceil(s.countdown_s) + " s" : "");
    const p = s.progress;
    const state = s.calibrated ? "done" : p ? p.state : "waiting";
    q(".state").textContent = STATES[state] || state;
    q(".state").className = "state " + state;
    q("progress").max = p ? p.n_required : 120;
    q("progress").value = s.calibrated ? q("progress").max : p ? p.n_collected : 0;
    q(".count").textContent = p ? `${s.calibrated ? p.n_required : p.n_collected}/${p.n_required}` : "";
    put(".message", s.message);
    const c = s.calibration;
    q(".cal").textContent = c ? `Initial angle to the sensor ${c.initial_angle_deg === null ? "—" : c.initial_angle_deg.toFixed(1) + "°"}; centre ${c.centre_m.map((v) => v.toFixed(2)).join(", ")} m; ${s.frames} frames (${s.joint_set}).` : "";
  }

  function render(s) {
    last = s;
    for (const side of ["a", "b"]) renderSide(document.querySelector(`#sides .side[data-side=${side}]`), s && s.sides[side]);
    drawSkeletons(s);
    const c = s && s.comparison;
    $("score").textContent = c && c.ready ? c.similarity.toFixed(0) : "—";
    $("meaning").textContent = c ? (c.ready ? c.meaning : c.message) : "Both users must be calibrated first.";
    $("meaning").className = c && c.mismatch ? "warn" : "";
    if (c && c.ready) {
      const sel = $("joint");
      if (sel.options.length !== c.joints.length + 1) {
        const keep = sel.value;
        sel.replaceChildren(el("option", {}, "Mean of all joints"), ...c.joints.map((j, i) => { const o = el("option", {}, j); o.value = String(i); return o; }));
        sel.options[0].value = "-1"; sel.value = keep;
      }
    }
    drawDiff(c && c.ready ? c : null);
  }

  function drawBody(ctx, sk, bones, color, ox, oy, scale) {
    if (!sk) return;
    const P = sk.positions;
    const px = (p) => [ox + p[1] * scale, oy - p[2] * scale];  // front view: +Y to the right, Z up
    ctx.strokeStyle = color; ctx.lineWidth = 3; ctx.lineCap = "round";
    for (const [a, b] of bones) {
      if (!P[a] || !P[b] || P[a][0] === null || P[b][0] === null) continue;
      const [x1, y1] = px(P[a]), [x2, y2] = px(P[b]);
      ctx.beginPath(); ctx.moveTo(x1, y1); ctx.lineTo(x2, y2); ctx.stroke();
    }
    ctx.fillStyle = color;
    for (const p of P) { if (!p || p[0] === null) continue; const [x, y] = px(p); ctx.beginPath(); ctx.arc(x, y, 3, 0, 2 * Math.PI); ctx.fill(); }
  }
  function drawSkeletons(s) {
    const cv = $("skeletons"), ctx = cv.getContext("2d");
    ctx.clearRect(0, 0, cv.width, cv.height);
    const scale = 190, floor = cv.height - 20;
    ctx.fillStyle = "#5b6470"; ctx.font = "15px system-ui";
    const cols = [[170, "User A"], [500, "User B"], [830, "Overlay"]];
    for (const [x, t] of cols) { ctx.fillText(t, x - 25, 22); }
    ctx.strokeStyle = "#e3e6ea"; ctx.lineWidth = 1;
    ctx.beginPath(); ctx.moveTo(0, floor); ctx.lineTo(cv.width, floor); ctx.stroke();
    if (!s) return;
    const A = s.sides.a, B = s.sides.b;
    if (!A.skeleton && !B.skeleton) {
      ctx.fillStyle = "#5b6470"; ctx.fillText("The skeletons appear here once each user is calibrated.", 300, 200); return;
    }
    // the universal origin is the body centre: put the lowest joint on the floor line
    const zs = [A.skeleton, B.skeleton].filter(Boolean).flatMap((k) => k.positions)
      .filter((p) => p && p[2] !== null).map((p) => p[2]);
    const oy = floor + Math.min(...zs) * scale;
    drawBody(ctx, A.skeleton, A.bones, COLORS.a, 170, oy, scale);
    drawBody(ctx, B.skeleton, B.bones, COLORS.b, 500, oy, scale);
    drawBody(ctx, A.skeleton, A.bones, COLORS.a, 830, oy, scale);
    drawBody(ctx, B.skeleton, B.bones, COLORS.b, 830, oy, scale);
  }

  function drawDiff(c) {
    const cv = $("diff"), ctx = cv.getContext("2d");
    ctx.clearRect(0, 0, cv.width, cv.height);
    const L = 55, R = cv.width - 15, T = 15, Bm = cv.height - 35;
    ctx.strokeStyle = "#b8bec6"; ctx.lineWidth = 1; ctx.strokeRect(L, T, R - L, Bm - T);
    ctx.fillStyle = "#5b6470"; ctx.font = "13px system-ui";
    ctx.fillText("cm", 14, T + 4); ctx.fillText("seconds before now", (L + R) / 2 - 60, cv.height - 8);
    if (!c) { ctx.fillText("No comparison yet.", L + 20, (T + Bm) / 2); return; }
    const j = Number($("joint").value);
    const ys = (j < 0 ? c.mean_m : c.per_joint_m[j]).map((v) => (v === null ? null : v * 100));
    const finite = ys.filter((v) => v !== null);
    const ymax = Math.max(5, ...finite) * 1.15;
    const t0 = Math.min(...c.times, -1), t1 = 0;
    const X = (t) => L + ((t - t0) / (t1 - t0)) * (R - L), Y = (v) => Bm - (v / ymax) * (Bm - T);
    for (let k = 0; k < 4; k++) { const v = (ymax * k) / 4; ctx.fillText(v.toFixed(ymax < 10 ? 1 : 0), 18, Y(v) + 4);
      ctx.strokeStyle = "#eef0f3"; ctx.beginPath(); ctx.moveTo(L, Y(v)); ctx.lineTo(R, Y(v)); ctx.stroke(); }
    for (let t = Math.ceil(t0 / 5) * 5; t <= 0; t += 5) ctx.fillText(String(t), X(t) - 8, Bm + 16);
    ctx.strokeStyle = "#12355b"; ctx.lineWidth = 2; ctx.beginPath();
    let pen = false;
    c.times.forEach((t, i) => { const v = ys[i]; if (v === null) { pen = false; return; }
      if (pen) ctx.lineTo(X(t), Y(v)); else ctx.moveTo(X(t), Y(v)); pen = true; });
    ctx.stroke();
  }
  $("joint").addEventListener("change", () => drawDiff(last && last.comparison && last.comparison.ready ? last.comparison : null));

  // ------------------------------------------------------------------- shares
  async function loadShares() {
    const shares = await api("/api/kscc/shares");
    $("shares").replaceChildren(...shares.map((s) => {
      const li = el("li", {}, `${s.node_id} is shared with other sites. `);
      const b = el("button", { class: "secondary" }, "Stop sharing"); b.type = "button";
      b.addEventListener("click", async () => {
        try { await api(`/api/kscc/shares/${encodeURIComponent(s.node_id)}`, { method: "DELETE" }); $("error").textContent = ""; }
        catch (e) { $("error").textContent = `Stop sharing ${s.node_id} failed: ${e.message}`; $("error").scrollIntoView(); }
        loadShares().catch(() => {});
      });
      li.append(b); return li;
    }));
    if (!shares.length) $("shares").append(el("li", {}, "No sensor is shared."));
  }
  $("suggest").addEventListener("click", () => {
    const b = new Uint8Array(12); crypto.getRandomValues(b);
    $("share-token").value = "k" + Array.from(b, (x) => x.toString(16).padStart(2, "0")).join("") + "7";
  });
  $("share-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    try { await api("/api/kscc/shares", { method: "POST", body: JSON.stringify({ node_id: $("share-node").value, token: $("share-token").value }) }); await loadShares(); $("error").textContent = ""; }
    catch (e) { $("error").textContent = "Sharing failed: " + e.message; $("error").scrollIntoView(); }
  });

  // -------------------------------------------------------------- active area
  const trapCells = (t) => t ? [cm(t.near_m), cm(t.far_m), cm(t.near_width_m), cm(t.far_width_m)] : ["—", "—", "—", "—"];
  function row(cells) { const tr = el("tr"); cells.forEach((c, i) => { const td = el(i ? "td" : "th", {}, c); if (!i) td.scope = "row"; tr.append(td); }); return tr; }
  async function loadAreas() {
    const rows = await api("/api/kscc/active-area");
    $("areas").replaceChildren(...rows.map((r) => {
      if (!r.presets) return row([r.node_id, r.height_m === null ? "—" : r.height_m.toFixed(2) + " m", "—", r.model, r.problem || "—", "", "", ""]);
      const p = r.presets[r.preset];
      const tr = row([r.node_id, r.height_m.toFixed(2) + " m", r.tilt_deg.toFixed(1) + "°", p.label, ...trapCells(p.trapezoid)]);
      tr.dataset.node = r.node_id; return tr;
    }));
    if (!rows.length) $("areas").append(row(["No sensor connected yet.", "", "", "", "", "", "", ""]));
  }
  async function loadPresets() {
    // one request per keystroke: an answer for what the fields no longer say is dropped
    const h = $("height").value, t = $("tilt").value;
    const current = () => $("height").value === h && $("tilt").value === t;
    try {
      const d = await api(`/api/kscc/trapezoid?height_m=${encodeURIComponent(h)}&tilt_deg=${encodeURIComponent(t)}`);
      if (!current()) return;
      $("presets").replaceChildren(...Object.entries(d.presets).map(([k, p]) => {
        let tr;
        if (p.trapezoid) tr = row([p.label, ...trapCells(p.trapezoid)]);
        else { tr = row([p.label, p.problem]); tr.lastChild.colSpan = 4; tr.lastChild.className = "warn"; }
        tr.dataset.preset = k; return tr; }));
    } catch (e) { if (current()) $("presets").replaceChildren(row(["Height or tilt out of range: " + e.message, "", "", "", ""])); }
  }
  $("height").addEventListener("input", loadPresets);
  $("tilt").addEventListener("input", loadPresets);

  (async () => {
    await Promise.all([loadSources(), loadShares(), loadAreas(), loadPresets()]).catch((e) => { $("error").textContent = e.message; });
    // a session running already (started elsewhere) is shown; unless the user started or
    // stopped one meanwhile, which this answer may predate
    const asked = generation, n = shown.ask();
    try { const s = await api("/api/kscc/session"); if (asked === generation && shown.fresh(n)) { if (s.running) { render(s); startPolling(); } else render(null); } }
    catch (e) { if (asked === generation) render(null); }
    gaitrig.poll(() => { loadSources().catch(() => {}); loadAreas().catch(() => {}); }, 5000);
  })();
})();
