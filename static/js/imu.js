// IMU page: upload IMU files (+ depth skeleton) or run a simulated session; show sync,
// joint angles (depth only vs fused), accuracy, warnings; offer the CSV.
"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  const el = gaitrig.el;
  const deg = (v) => (v === null || v === undefined ? "—" : v.toFixed(1) + "°");
  const row = (...cells) => { const tr = el("tr"); cells.forEach((c, i) => { const td = el(i ? "td" : "th", {}, c); if (!i) td.scope = "row"; tr.append(td); }); return tr; };

  async function call(path, options) {
    // multipart bodies must not get the JSON content type, so no gaitrig.api() here
    const r = await fetch(path, { credentials: "same-origin", ...options });
    if (r.status === 401) { gaitrig.toLogin(); throw new Error("not logged in"); }
    let body = null; try { body = await r.json(); } catch (e) { /* not JSON */ }
    if (!r.ok) throw new Error((body && body.detail) || r.statusText);
    return body;
  }

  function busy(on) {
    $("busy").hidden = !on;
    $("upload").disabled = on; $("simulate").disabled = on;
  }

  function show(d) {
    $("result").hidden = false;
    $("note").textContent = d.note || (d.kind === "fused"
      ? `Fused ${d.sensors.length} IMUs with ${d.skeleton.frames} depth frames (${d.skeleton.joint_set}); plank pose at ${d.plank_time_s.toFixed(1)} s, reference frame at ${d.reference_frame_time_s.toFixed(1)} s.`
      : "");
    const filt = d.filter === "madgwick" ? `Madgwick, β = ${d.beta}` : "gaitrig filter";
    $("note").textContent += ` Filter: ${filt}.`;
    $("warnings").replaceChildren(...(d.warnings || []).map((w) => el("li", {}, w)));
    if (!(d.warnings || []).length) $("warnings").replaceChildren(el("li", { class: "ok" }, "No problems found in the files."));
    $("csv").href = d.csv_url;
    $("sensor-rows").replaceChildren(...d.sensors.map((s) => row(s.name, s.format, String(s.samples),
      s.frequency_hz.toFixed(1) + " Hz", s.duration_s.toFixed(1) + " s", s.magnetometer ? "yes" : "no")));
    // orientation error vs an optical reference (BROAD files)
    $("reference-card").hidden = !d.reference_errors;
    if (d.reference_errors) {
      $("reference-rows").replaceChildren(...Object.entries(d.reference_errors).map(([n, e]) =>
        row(n, deg(e.total_deg), deg(e.heading_deg), deg(e.inclination_deg))));
    }
    // accuracy (simulation)
    $("accuracy-card").hidden = !d.accuracy;
    if (d.accuracy) {
      $("accuracy-rows").replaceChildren(...Object.values(d.accuracy).map((a) => {
        const tr = row(a.label, deg(a.depth_rmse_deg), deg(a.fused_rmse_deg), a.depth_ncc.toFixed(2), a.fused_ncc.toFixed(2));
        if (a.fused_rmse_deg < a.depth_rmse_deg) tr.children[2].className = "better";
        tr.dataset.joint = a.label; return tr;
      }));
    }
    // sync
    const hasSync = !!(d.sync || (d.plots && d.plots.sync));
    $("sync-card").hidden = !hasSync;
    if (d.sync) {
      const worst = Math.max(...d.sync.map((s) => s.max_residual_ms));
      $("sync-text").textContent = `${d.sync.length} streams aligned to the ${d.sync.some((s) => s.stream === "skeleton") ? "depth skeleton's" : "first stream's"} clock; the jumps agree within ${worst.toFixed(1)} ms after alignment.`;
      $("sync-rows").replaceChildren(...d.sync.map((s) => row(s.stream, (s.offset_s >= 0 ? "+" : "") + s.offset_s.toFixed(3) + " s",
        s.spikes_s.map((x) => x.toFixed(2)).join(", ") + " s", `max ${s.max_residual_ms.toFixed(1)} ms`)));
    } else if (d.spikes) {
      $("sync-text").textContent = "Jump landings found per stream (not aligned: one stream, or not every stream has the jumps).";
      $("sync-rows").replaceChildren(...Object.entries(d.spikes).map(([n, s]) => row(n, "—", s.map((x) => x.toFixed(2)).join(", ") + " s", "—")));
    }
    const plot = (name) => {
      const card = $(name + "-card"), img = $(name + "-plot");
      card.hidden = !(d.plots && d.plots[name]);
      if (!card.hidden) img.src = d.plots[name];
    };
    plot("sync"); plot("angles"); plot("orientation");
    if (d.angles) {
      $("angles-text").textContent = Object.values(d.angles).map((a) =>
        `${a.label}: ${a.fused_range_deg ? deg(a.fused_range_deg[0]) + "–" + deg(a.fused_range_deg[1]) : "—"} (depth vs fused differ by ${deg(a.depth_vs_fused_rmse_deg)} RMS)`).join("; ") + ".";
    }
    $("summary-h").focus();
  }

  $("upload-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    $("error").textContent = "";
    const fd = new FormData();
    for (const f of $("files").files) fd.append("files", f);
    for (const n of $("sensors").value.split(",").map((s) => s.trim()).filter(Boolean)) fd.append("sensors", n);
    if ($("file_sensors").value.trim()) for (const c of $("file_sensors").value.split(",")) fd.append("file_sensors", c.trim());
    if ($("skeleton").files.length) fd.append("skeleton", $("skeleton").files[0]);
    else if ($("recording").value) {
      const [rec, node] = $("recording").value.split("|");
      fd.append("recording", rec); fd.append("recording_node", node);
    }
    fd.append("filter", $("filter").value);
    fd.append("beta", $("beta").value);
    fd.append("n_jumps", $("n_jumps").value);
    fd.append("synchronise", $("synchronise").checked ? "true" : "false");
    for (const u of ["gyr_unit", "acc_unit", "mag_unit", "time_unit", "quat_order", "quat_frame"]) if ($(u).value) fd.append(u, $(u).value);
    busy(true);
    try { show(await call("/api/imu/sessions", { method: "POST", body: fd })); }
    catch (e) { $("error").textContent = e.message; }
    finally { busy(false); }
  });

  $("simulate").addEventListener("click", async () => {
    $("error").textContent = "";
    busy(true);
    try {
      show(await call("/api/imu/simulate", { method: "POST", headers: { "Content-Type": "application/json" },
        body: JSON.stringify({ filter: $("filter").value, beta: Number($("beta").value) }) }));
    } catch (e) { $("error").textContent = e.message; }
    finally { busy(false); }
  });
  $("summary-h").tabIndex = -1;
  // recordings already on the server: each sensor's skeleton can be the depth source
  call("/api/imu/recordings").then((recs) => {
    for (const r of recs) for (const n of r.sensors) {
      const o = el("option", {}, `${r.id} — sensor ${n}`); o.value = `${r.id}|${n}`; $("recording").append(o);
    }
  }).catch(() => {});
})();
