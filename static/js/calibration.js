// Calibration wizard: marker sheet, capture from the connected sensors (progress, graph,
// residual tables, accept/reject), simulated run, live bumped-tripod check, saved versions.
"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  const el = gaitrig.el;
  function row(cells) {
    const tr = el("tr");
    for (const c of cells) { const td = el("td"); td.append(c); tr.append(td); }
    return tr;
  }
  const mm = (v) => (v === null || v === undefined ? "—" : (v * 1000).toFixed(1));
  // What a calibration's worst error against the markers means for the person who accepts
  // it (the help's rule of thumb: under 3 mm accept; a red line is a marker to fix; above
  // 10 mm the gait report warns that step width is not to be relied on).
  function verdict(worstM, pending) {
    const v = worstM * 1000;
    if (v < 3) return { cls: "verdict-good", text: "good (under 3 mm)" + (pending ? ": accept it" : "") };
    if (v <= 10) return { cls: "verdict-check", text: "fair (3–10 mm): a red line in the graph shows a marker "
      + "that is wrinkled, partly covered or seen very obliquely; fix it and capture again if you can" };
    return { cls: "verdict-bad", text: "too large (over 10 mm): step width would not be reliable; "
      + "fix the markers on the red lines and capture again" };
  }
  // The depth-image fine-tuning (ICP) of one sensor in plain words; the engine's reason and
  // figures stay in the cell's title and the technical figures.
  function icpPlain(r) {
    if (r.accepted) return "kept: the sensors' depth images now line up better";
    const why = r.reason || "";
    const plain = /overlap with the other/.test(why) ? "this sensor's view overlaps the others' too little"
      : /degenerate|one plane/.test(why) ? "it sees mostly floor, which cannot steady it"
      : /did not improve/.test(why) ? "it would not have improved the fit"
      : /moved the sensor/.test(why) ? "it disagreed with the markers too much"
      : "";
    return "not kept" + (plain ? `: ${plain}` : "") + " — the markers alone place this sensor";
  }
  const icpFigures = (r) => (r.fitness !== undefined
    ? `ICP fitness ${r.fitness_before.toFixed(2)}→${r.fitness.toFixed(2)}, inlier RMSE `
      + `${r.inlier_rmse_before_mm.toFixed(1)}→${r.inlier_rmse_mm.toFixed(1)} mm` : "ICP did not run");

  $("sheet-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const btn = ev.target.querySelector("button");
    // progress and success in the status line, a refusal in the alert under it
    const say = (text, cls) => {
      const ok = cls !== "warn";
      $("sheet-state").textContent = ok ? text : ""; $("sheet-state").className = cls;
      $("sheet-error").textContent = ok ? "" : text;
    };
    const q = new URLSearchParams({ ids: $("sheet-ids").value, size: String(Number($("sheet-size").value) / 100),
      paper: $("sheet-paper").value });
    // the sheet takes seconds to draw: the button said nothing meanwhile (pressed again?)
    say("Making the marker sheet… (this can take a few seconds)", "");
    btn.disabled = true;
    try {
      let r;
      try { r = await fetch("/api/calibration/markers.pdf?" + q, { credentials: "same-origin" }); }
      catch (e) { say("No answer from the server: check that it is running.", "warn"); return; }
      if (r.status === 401) { gaitrig.toLogin(); return; }
      if (!r.ok) {
        let d = r.statusText; try { const j = await r.json(); d = typeof j.detail === "string" ? j.detail : "check the size (2–50 cm)"; } catch (e) {}
        say(d, "warn"); return;
      }
      const url = URL.createObjectURL(await r.blob());
      const a = el("a", { href: url, download: "markers.pdf" });
      document.body.append(a); a.click(); a.remove();
      setTimeout(() => URL.revokeObjectURL(url), 10000);
      say("Marker sheet downloaded (markers.pdf): print it at 100 % and check the scale bar.", "good");
    } finally { gaitrig.release(btn); }
  });

  const SVGNS = "http://www.w3.org/2000/svg";
  function svg(tag, attrs, text) {
    const e = document.createElementNS(SVGNS, tag);
    for (const [k, v] of Object.entries(attrs)) e.setAttribute(k, String(v));
    if (text !== undefined) e.textContent = text;
    return e;
  }
  const edgeColour = (r) => (r === null || r === undefined ? "#999" : r < 0.001 ? "#28a046" : r < 0.003 ? "#dcaa14" : "#d23228");

  function drawGraph(doc) {
    const g = $("graph"); g.replaceChildren();
    const S = Object.fromEntries(Object.entries(doc.T_world_sensor).map(([k, T]) => [k, [T[0][3], T[1][3]]]));
    const M = Object.fromEntries(Object.entries(doc.T_world_marker).map(([k, T]) => [k, [T[0][3], T[1][3]]]));
    const pts = [...Object.values(S), ...Object.values(M)];
    if (!pts.length) return;
    const xs = pts.map((p) => p[0]), ys = pts.map((p) => p[1]);
    const x0 = Math.min(...xs), x1 = Math.max(...xs), y0 = Math.min(...ys), y1 = Math.max(...ys);
    const W = 640, H = 360, pad = 40;
    const k = Math.min((W - 2 * pad) / Math.max(x1 - x0, 0.1), (H - 2 * pad) / Math.max(y1 - y0, 0.1));
    // centred; Z up: world y points up on screen
    const ox = (W - (x1 - x0) * k) / 2, oy = (H - (y1 - y0) * k) / 2;
    const P = (p) => [ox + (p[0] - x0) * k, H - oy - (p[1] - y0) * k];
    for (const e of doc.edges) {
      if (!S[e.sensor] || !M[String(e.marker)]) continue;
      const [ax, ay] = P(S[e.sensor]), [bx, by] = P(M[String(e.marker)]);
      const ln = svg("line", { x1: ax, y1: ay, x2: bx, y2: by, stroke: edgeColour(e.residual_m),
        "stroke-width": e.in_chain ? 4 : 2, class: "edge" });
      ln.append(svg("title", {}, `${e.sensor} – marker ${e.marker}: ${mm(e.residual_m)} mm`));
      g.append(ln);
    }
    for (const [m, p] of Object.entries(M)) {
      const [x, y] = P(p);
      g.append(svg("rect", { x: x - 7, y: y - 7, width: 14, height: 14, fill: m === "1" ? "#111" : "#555", class: "marker" }));
      g.append(svg("text", { x: x + 9, y: y + 4, "font-size": 12 }, m));
    }
    for (const [s, p] of Object.entries(S)) {
      const [x, y] = P(p);
      g.append(svg("circle", { cx: x, cy: y, r: 9, fill: "#0b5cad", class: "sensor" }));
      g.append(svg("text", { x: x + 11, y: y - 8, "font-size": 13, "font-weight": 600 }, s));
    }
  }

  function show(doc, pending) {
    const sens = Object.keys(doc.T_world_sensor).sort();
    const worst = Math.max(...sens.map((s) => doc.sensor_residual_m[s] || 0));
    const head = pending ? "New calibration, not saved yet" : `Version ${doc.version}`;
    // the local time, as in the saved-versions table (was the raw "2026-11-24T17:14:50Z")
    const when = gaitrig.dateTime(gaitrig.when(doc.created_iso));
    // in words first ("worst sensor residual 1.39 mm" told a clinician nothing); the
    // exact figure and the graph's size are in the title and the technical figures
    const markers = new Set(doc.edges.map((e) => e.marker)).size;
    const v = verdict(worst, pending);
    const summary = $("res-summary");
    summary.replaceChildren(`${head} (${when}, ${doc.meta.source || "captured"}): `
      + `${gaitrig.plural(sens.length, "sensor")} placed from ${gaitrig.plural(markers, "marker")}. `
      + `Error against the markers: ${(worst * 1000).toFixed(1)} mm at worst — `,
      el("span", { class: v.cls, "data-verdict": v.cls.slice(8) }, v.text), ".");
    summary.title = `worst sensor residual ${(worst * 1000).toFixed(2)} mm; `
      + `${gaitrig.plural(doc.edges.length, "sensor–marker edge")}`;
    $("res-details").hidden = false; $("res-empty").hidden = true;
    drawGraph(doc);
    const icp = Object.fromEntries((doc.meta.icp || []).map((r) => [r.sensor, r]));
    const tb = $("sensor-table").querySelector("tbody"); tb.replaceChildren();
    // only a simulated run knows the true poses: for a real rig the two columns were dashes
    // under a heading that meant nothing there
    const truth = !!doc.true_errors;
    for (const th of $("sensor-table").querySelectorAll("th.truth")) th.hidden = !truth;
    for (const s of sens) {
      const T = doc.T_world_sensor[s];
      const e = (doc.true_errors || {})[s];
      const c = e ? `${(e.chained_pos_m * 1000).toFixed(1)} / ${e.chained_rot_deg.toFixed(2)}` : "—";
      const fp = e ? (e.final_pos_m ?? e.optimised_pos_m) : null, fr = e ? (e.final_rot_deg ?? e.optimised_rot_deg) : null;
      const o = el("span", {}, e ? `${(fp * 1000).toFixed(1)} / ${fr.toFixed(2)}` : "—");
      if (e) o.className = fp <= 0.01 && fr <= 0.5 ? "good" : "warn";
      const r = icp[s];
      // (was "not kept (fitness 0.77→0.77, RMSE 16.0→16.0 mm)": the figures are in the title)
      const icpCell = el("span", r ? { title: `${r.reason}; ${icpFigures(r)}` } : {}, r ? icpPlain(r) : "—");
      const res = doc.sensor_residual_m[s];
      const resCell = el("span", { title: `residual ${res === undefined || res === null ? "—" : (res * 1000).toFixed(2)} mm` }, mm(res));
      if (res !== undefined && res !== null) resCell.className = res < 0.003 ? "good" : "warn";
      tb.append(row([s, `${T[0][3].toFixed(3)}, ${T[1][3].toFixed(3)}, ${T[2][3].toFixed(3)}`,
        resCell, icpCell, ...(truth ? [c, o] : [])]));
    }
    // the exact figures, for the research engineer
    const figs = $("res-figures-list");
    figs.replaceChildren(el("li", {}, `${gaitrig.plural(doc.edges.length, "sensor–marker edge")}; `
      + `worst sensor residual ${(worst * 1000).toFixed(2)} mm`));
    for (const s of sens) {
      const res = doc.sensor_residual_m[s];
      figs.append(el("li", { "data-sensor": s }, `${s}: residual ${res === undefined || res === null ? "—" : (res * 1000).toFixed(2)} mm; `
        + (icp[s] ? `${icp[s].accepted ? "ICP kept" : "ICP not kept"} (${icp[s].reason}); ${icpFigures(icp[s])}` : "no ICP report")));
    }
    const eb = $("edge-table").querySelector("tbody"); eb.replaceChildren();
    for (const e of doc.edges) {
      const r = el("span", {}, mm(e.residual_m)); r.className = e.residual_m < 0.003 ? "good" : "warn";
      eb.append(row([e.sensor, String(e.marker), e.distance_m === null ? "—" : e.distance_m.toFixed(2), r, e.in_chain ? "yes" : "no"]));
    }
    const ul = $("rejected"); ul.replaceChildren();
    const rej = doc.observations.filter((o) => !o.accepted);
    $("res-more-summary").textContent = `Each marker each sensor saw (${doc.edges.length}), `
      + `and the sightings left out (${rej.length ? rej.length : "none"})`;
    if (!rej.length) ul.append(el("li", {}, "None."));
    for (const o of rej) ul.append(el("li", {}, `${o.sensor} · marker ${o.marker}: ${o.reason}`));
    return v;
  }

  const sleep = gaitrig.wait;  // (a watch of the job pauses while the page is hidden)
  // The job runs on the server whatever happens to one poll: a poll that finds the server
  // busy or unreachable (no answer, 5xx) is retried a few times before giving up, so a
  // blip does not end the watch of a capture that carries on.
  async function poll(id, onTick) {
    let failures = 0;
    for (;;) {
      let j;
      try { j = await gaitrig.api(`/api/calibration/captures/${id}`); failures = 0; }
      catch (e) {
        if ((e.status && e.status < 500) || ++failures > 5) throw e;
        await sleep(1500);
        continue;
      }
      onTick(j);
      if (j.state !== "capturing" && j.state !== "computing") return j;
      await sleep(700);
    }
  }

  function progress(j) {
    const t = $("cap-progress"); t.hidden = false;
    const tb = t.querySelector("tbody"); tb.replaceChildren();
    for (const [n, p] of Object.entries(j.nodes)) {
      const bar = el("progress", { max: String(j.frames), value: String(p.received), "aria-label": `${n} frames` });
      const cell = el("span"); cell.append(bar, ` ${p.received} / ${j.frames}`);
      tb.append(row([n, cell, p.error || ""]));
    }
    $("cap-state").textContent = j.state === "capturing" ? "Capturing…" : j.state === "computing"
      ? "Computing the sensor poses from the markers…" : "";
  }

  // A result that was asked for (a capture, a simulated run, a restore) is shown and the
  // focus goes to its summary, the verdict in words: a screen reader reads it once, as the
  // focus, and Tab leads on through the result (to Accept when one is asked). The summary is
  // not a live region: it was, and the verdict was read twice (as news, then as the focus).
  function focusResult() {
    $("res-h").scrollIntoView({ block: "start" });  // (the result is below the fold)
    $("res-summary").focus({ preventScroll: true });
  }

  let pendingJob = null;
  // The Accept/Reject box sits right under the result it judges (it was in step 2, above
  // the result, away from what it accepts); a refusal is said in it, the outcome under it.
  // A result whose error is too large (over 10 mm) is accepted only once the person ticks
  // that they know what it costs: one press of the usual button saved a calibration the
  // page itself called unreliable.
  function decide(open, tooLarge = false) {
    $("decide").hidden = !open;
    $("decide-error").textContent = ""; $("decide-state").textContent = "";
    $("decide-bad").hidden = !tooLarge; $("accept-bad").checked = false;
    $("accept").disabled = open && tooLarge;
  }
  $("accept-bad").addEventListener("change", (ev) => { $("accept").disabled = !ev.currentTarget.checked; });
  $("cap-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    $("cap-error").textContent = ""; decide(false); pendingJob = null;
    const btn = ev.target.querySelector("button"); btn.disabled = true;
    try {
      const j0 = await gaitrig.api("/api/calibration/capture", { method: "POST", body: JSON.stringify({
        ids: $("cap-ids").value, size_m: Number($("cap-size").value) / 100, frames: Number($("cap-frames").value) }) });
      const j = await poll(j0.id, progress);
      if (j.state === "failed") {
        $("cap-state").textContent = "Calibration failed.";
        $("cap-error").textContent = j.message + (j.unreachable ? ` (unreachable: ${j.unreachable.join(", ")})` : "");
        $("cap-error").append(" ", el("a", { href: "/help.html#ts-calibration-fails" }, "What does this mean?"));
      } else if (j.state === "done") {
        $("cap-state").textContent = "Done: check the result in step 3, then accept or reject it under the result.";
        shownSeq.acted(); const v = show(j.result, true);
        pendingJob = j.id; decide(true, v.cls === "verdict-bad");
        focusResult();  // (the verdict is read once; the box to accept it follows)
      }
    } catch (e) {
      $("cap-error").textContent = String(e.message || e);
    } finally { gaitrig.release(btn); }
  });
  // Accept and Reject say why they failed (they failed silently: an unhandled rejection,
  // the buttons still there and nothing said). Both are disabled while one is asked (a
  // second press reported "Not saved" for a calibration the first had saved); once
  // decided the box closes and the focus goes to the outcome under it (not to the page).
  // The outcome is not a live region: the focus reads it, once (a clinician who pressed
  // Accept hears "Saved as version 7 …" where the buttons were, not the same words twice).
  async function decideWith(pressed, path, failed, done) {
    if (pendingJob === null) return;
    // (the pressed one first: it gets the focus back)
    const btns = [pressed, pressed.id === "accept" ? $("reject") : $("accept")];
    $("decide-error").textContent = "";
    for (const b of btns) b.disabled = true;
    let r;
    try { r = await gaitrig.api(`/api/calibration/captures/${pendingJob}/${path}`, { method: "POST" }); }
    catch (e) {
      $("decide-error").textContent = `${failed}: ${e.message || e}`;
      for (const b of btns) gaitrig.release(b);
      return;
    }
    decide(false); pendingJob = null;
    for (const b of btns) b.disabled = false;
    $("cap-state").textContent = "";  // ("Done: check the result…" no longer holds)
    $("decide-state").textContent = done(r);
    $("decide-state").focus();
    await refresh();
  }
  $("accept").addEventListener("click", (ev) => decideWith(ev.currentTarget, "accept", "Not saved",
    (r) => `Saved as version ${r.version} and applied to ${r.applied_to.join(", ") || "no sensor"}.`));
  $("reject").addEventListener("click", (ev) => decideWith(ev.currentTarget, "reject", "Not rejected",
    () => "Rejected: the active calibration is unchanged."));

  function showCheck(j) {
    const t = $("check-table"); t.hidden = false;
    const tb = t.querySelector("tbody"); tb.replaceChildren();
    for (const c of j.checks || []) {
      const st = el("span", {}, c.status); st.className = c.status === "ok" ? "good" : "warn";
      tb.append(row([c.sensor, st, c.moved_mm === null ? "—" : c.moved_mm.toFixed(1),
        c.rotated_deg === null ? "—" : c.rotated_deg.toFixed(2), (c.markers || []).join(" "), c.reason || ""]));
    }
    const moved = j.moved || [];
    $("check-state").textContent = j.state === "failed" ? j.message
      : moved.length ? `Warning: ${moved.join(", ")} moved since the calibration — recalibrate before recording.`
      : j.message;
    $("check-state").className = moved.length || j.state === "failed" ? "warn" : "good";
  }
  $("check-btn").addEventListener("click", async (ev) => {
    const btn = ev.target; btn.disabled = true;
    $("check-state").className = ""; $("check-state").textContent = "Capturing fresh frames…";
    try {
      const j0 = await gaitrig.api("/api/calibration/live-check", { method: "POST", body: JSON.stringify({ frames: 5 }) });
      showCheck(await poll(j0.id, () => {}));
    } catch (e) {
      $("check-state").className = "warn"; $("check-state").textContent = String(e.message || e);
    } finally { gaitrig.release(btn); }
  });

  // versions lists overlap (page load, accept, restore, a simulated run): one asked
  // before a newer one is not drawn, else it would hide the version just saved
  const historySeq = gaitrig.latest();
  async function history() {
    const mine = historySeq.ask();
    const rows = await gaitrig.api("/api/calibration");
    if (!historySeq.current(mine)) return rows;
    const tb = $("history").querySelector("tbody"); tb.replaceChildren();
    // (headings over nothing looked like a list still loading)
    if (!rows.length) {
      const tr = el("tr");
      tr.append(el("td", { colspan: "6" }, "No saved calibration yet: capture one in step 2 and accept it."));
      tb.append(tr);
    }
    rows.forEach((c, i) => {
      const btn = el("button", { type: "button" }, i === 0 ? "active" : "Restore");
      if (i === 0) btn.disabled = true;
      // (the active version's disabled button was announced as "Restore calibration …")
      btn.setAttribute("aria-label", i === 0 ? `Calibration version ${c.version} is active`
        : `Restore calibration version ${c.version}`);
      btn.addEventListener("click", async () => {
        $("hist-msg").textContent = "";
        try { await gaitrig.api(`/api/calibration/${c.version}/restore`, { method: "POST" }); }
        catch (e) { $("hist-msg").textContent = `Version ${c.version} not restored: ${e.message || e}`; return; }
        await refresh();
        // the redrawn list took the pressed button (and the focus) away: the focus goes to
        // the verdict of the version now in use, the one restored (the summary is no live
        // region: it said so as one while the focus fell to the page)
        if (pendingJob === null) focusResult();
      });
      tb.append(row([String(c.version), gaitrig.dateTime(c.created), c.sensors.join(" "),
        c.max_sensor_residual_mm === null ? "—" : c.max_sensor_residual_mm.toFixed(2), String(c.rejected), btn]));
    });
    return rows;
  }

  // the active calibration asked for before a simulated run or a capture finished must
  // not replace that newer result on the page
  const shownSeq = gaitrig.latest();
  async function refresh() {
    const n = shownSeq.ask();
    const rows = await history();
    $("res-empty").hidden = !(!rows.length && pendingJob === null && shownSeq.current(n)
      && $("res-details").hidden);
    if (!rows.length || pendingJob !== null) return;
    const active = await gaitrig.api("/api/calibration/active");
    if (shownSeq.current(n) && pendingJob === null) show(active, false);
  }

  $("sim-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    $("sim-error").textContent = "";
    $("cal-busy").hidden = false;
    const btn = ev.target.querySelector("button"); btn.disabled = true;
    try {
      const doc = await gaitrig.api("/api/calibration/simulate", { method: "POST",
        body: JSON.stringify({ frames: Number($("sim-frames").value), seed: Number($("sim-seed").value) }) });
      shownSeq.acted(); show(doc, false);
      focusResult();  // as after a capture: its verdict, read once
      await history();
    } catch (e) {
      $("sim-error").textContent = String(e.message || e);
    } finally { $("cal-busy").hidden = true; gaitrig.release(btn); }
  });

  // The edge length printed in step 1 and the one entered in step 2 must be the same
  // markers' (a 20 cm sheet captured as 40 cm puts every sensor twice as far away), yet
  // step 2 starts from the room's markers: a clinician changing the printed size saw step 2
  // keep another number. Step 2 follows step 1 until it is typed in, and a difference is said.
  let capTyped = false;
  $("cap-size").addEventListener("input", () => { capTyped = true; sizeNote(); });
  $("sheet-size").addEventListener("input", () => {
    if (!capTyped && Number($("sheet-size").value) >= 2) $("cap-size").value = $("sheet-size").value;
    sizeNote();
  });
  function sizeNote() {
    const printed = Number($("sheet-size").value), entered = Number($("cap-size").value);
    const note = $("cap-size-note");
    const differ = printed > 0 && entered > 0 && Math.abs(printed - entered) > 1e-6;
    const text = differ ? `Not the ${printed} cm of the sheet in step 1: if the markers on the floor are `
      + `that sheet's, enter ${printed} here; else measure their black square.` : "";
    if (note.textContent !== text) note.textContent = text;
    note.hidden = !differ;
  }

  // The capture form starts from the markers the server expects (the active calibration's,
  // or the simulated room's); a field the user already changed is left alone.
  async function prefill() {
    const d = await gaitrig.api("/api/calibration/defaults");
    const ids = $("cap-ids"), size = $("cap-size");
    if (ids.value === ids.defaultValue) ids.value = d.marker_ids;
    if (size.value === size.defaultValue) size.value = String(Math.round(d.marker_size_m * 1000) / 10);
    $("cap-source").textContent = `Filled in from ${d.source}.`;
    sizeNote();
  }
  prefill().catch(() => {});
  refresh().catch((e) => { $("res-summary").textContent = String(e.message || e); });
})();
