// Calibration wizard: marker sheet, simulated capture, result tables, saved versions.
"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  function el(tag, text, attrs = {}) {
    const e = document.createElement(tag);
    if (text !== undefined && text !== null) e.textContent = text;
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, v);
    return e;
  }
  function row(cells) {
    const tr = el("tr");
    for (const c of cells) { const td = el("td"); td.append(c); tr.append(td); }
    return tr;
  }
  const mm = (v) => (v === null || v === undefined ? "—" : (v * 1000).toFixed(1));

  $("sheet-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    $("sheet-error").textContent = "";
    const q = new URLSearchParams({ ids: $("sheet-ids").value, size: String(Number($("sheet-size").value) / 100),
      paper: $("sheet-paper").value });
    const r = await fetch("/api/calibration/markers.pdf?" + q, { credentials: "same-origin" });
    if (!r.ok) {
      let d = r.statusText; try { const j = await r.json(); d = typeof j.detail === "string" ? j.detail : "check the size (2–50 cm)"; } catch (e) {}
      $("sheet-error").textContent = d; return;
    }
    const url = URL.createObjectURL(await r.blob());
    const a = el("a", "", { href: url, download: "markers.pdf" });
    document.body.append(a); a.click(); a.remove();
  });

  function show(doc) {
    const sens = Object.keys(doc.T_world_sensor).sort();
    const worst = Math.max(...sens.map((s) => doc.sensor_residual_m[s] || 0));
    $("res-summary").textContent = `Version ${doc.version} (${doc.created_iso}, ${doc.meta.source || "captured"}): `
      + `${sens.length} sensors, ${doc.edges.length} sensor–marker edges, worst sensor residual ${(worst * 1000).toFixed(2)} mm.`;
    const tb = $("sensor-table").querySelector("tbody"); tb.replaceChildren();
    for (const s of sens) {
      const T = doc.T_world_sensor[s];
      const e = (doc.true_errors || {})[s];
      const c = e ? `${(e.chained_pos_m * 1000).toFixed(1)} / ${e.chained_rot_deg.toFixed(2)}` : "—";
      const o = el("span", e ? `${(e.optimised_pos_m * 1000).toFixed(1)} / ${e.optimised_rot_deg.toFixed(2)}` : "—");
      if (e) o.className = e.optimised_pos_m <= 0.01 && e.optimised_rot_deg <= 0.5 ? "good" : "warn";
      tb.append(row([s, `${T[0][3].toFixed(3)}, ${T[1][3].toFixed(3)}, ${T[2][3].toFixed(3)}`,
        mm(doc.sensor_residual_m[s]), c, o]));
    }
    const eb = $("edge-table").querySelector("tbody"); eb.replaceChildren();
    for (const e of doc.edges) {
      const r = el("span", mm(e.residual_m)); r.className = e.residual_m < 0.003 ? "good" : "warn";
      eb.append(row([e.sensor, String(e.marker), e.distance_m === null ? "—" : e.distance_m.toFixed(2), r, e.in_chain ? "yes" : "no"]));
    }
    const ul = $("rejected"); ul.replaceChildren();
    const rej = doc.observations.filter((o) => !o.accepted);
    if (!rej.length) ul.append(el("li", "None."));
    for (const o of rej) ul.append(el("li", `${o.sensor} · marker ${o.marker}: ${o.reason}`));
  }

  async function history() {
    const rows = await gaitrig.api("/api/calibration");
    const tb = $("history").querySelector("tbody"); tb.replaceChildren();
    rows.forEach((c, i) => {
      const btn = el("button", i === 0 ? "active" : "Restore", { type: "button" });
      if (i === 0) btn.disabled = true;
      btn.setAttribute("aria-label", `Restore calibration version ${c.version}`);
      btn.addEventListener("click", async () => {
        await gaitrig.api(`/api/calibration/${c.version}/restore`, { method: "POST" });
        await refresh();
      });
      tb.append(row([String(c.version), new Date(c.created * 1000).toLocaleString(), c.sensors.join(" "),
        c.max_sensor_residual_mm === null ? "—" : c.max_sensor_residual_mm.toFixed(2), String(c.rejected), btn]));
    });
    return rows;
  }

  async function refresh() {
    const rows = await history();
    if (rows.length) show(await gaitrig.api("/api/calibration/active"));
  }

  $("sim-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    $("sim-error").textContent = "";
    $("cal-busy").hidden = false;
    const btn = ev.target.querySelector("button"); btn.disabled = true;
    try {
      const doc = await gaitrig.api("/api/calibration/simulate", { method: "POST",
        body: JSON.stringify({ frames: Number($("sim-frames").value), seed: Number($("sim-seed").value) }) });
      show(doc);
      await history();
    } catch (e) {
      $("sim-error").textContent = String(e.message || e);
    } finally { $("cal-busy").hidden = true; btn.disabled = false; }
  });

  refresh().catch((e) => { $("res-summary").textContent = String(e.message || e); });
})();
