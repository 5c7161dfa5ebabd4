// Bumped-tripod warning from the live check (re-detects the markers in fresh frames of
// every connected sensor and compares with the active calibration; the server also runs it
// periodically). Calibrate page: "check now" button and status (#bump-state). Rig and
// Record pages: a banner (#calib-warning) naming every sensor found moved.
"use strict";
(() => {
  const banner = document.getElementById("calib-warning");
  if (!banner) return;
  const fmt = (x, nd) => (x === null || x === undefined ? "?" : Number(x).toFixed(nd));
  function render(j) {
    const warnings = j.warnings || [];
    banner.replaceChildren();
    banner.hidden = !warnings.length;
    for (const w of warnings) {
      const p = document.createElement("p");
      const when = w.calibration_created ? gaitrig.dateTime(w.calibration_created) : `version ${w.calibration_version}`;
      p.append(`Sensor ${w.sensor} has moved ${fmt(w.moved_mm / 10, 1)} cm / ${fmt(w.rotated_deg, 1)}° since the calibration of ${when}. Recalibrate before recording. `);
      const a = document.createElement("a");
      a.href = "/calibration-wizard.html"; a.textContent = "Open the calibration wizard";
      const help = document.createElement("a");
      help.href = "/help.html#bumped-tripod"; help.textContent = "What does this mean?";
      p.append(a, " · ", help);
      banner.append(p);
    }
  }
  async function poll() {
    try { render(await gaitrig.api("/api/calibration/live-check")); } catch (e) { /* page shows its own errors */ }
    await gaitrig.wait(10000);  // (the next one not while the page is hidden)
    poll();
  }
  poll();
})();
(() => {
  const state = document.getElementById("bump-state");
  const btn = document.getElementById("bump-check");
  if (!state || !btn) return;
  function render(j) {
    if (!j.checked) {
      state.className = ""; state.textContent = "No live check yet: run one after moving people or equipment near the sensors.";
      return;
    }
    const when = gaitrig.moment(j.created);  // with its date when it was not today
    if (j.state === "failed") { state.className = "warn"; state.textContent = `Check at ${when} failed: ${j.message}`; return; }
    const unknown = (j.checks || []).filter((c) => c.status === "unknown").map((c) => `${c.sensor} (${c.reason})`);
    if (j.moved.length) {
      state.className = "warn";
      state.textContent = `Warning (${when}): ${j.message}`;
    } else {
      state.className = unknown.length ? "warn" : "good";
      state.textContent = `Checked at ${when}: no sensor moved more than 1 cm / 0.5°.`
        + (unknown.length ? ` Not checked: ${unknown.join("; ")}` : "");
    }
  }
  // the page's first request may be answered after "check now" was clicked: the older
  // check it describes must not replace the "Capturing…" status
  const lastSeq = gaitrig.latest();
  async function last() {
    const n = lastSeq.ask();
    const j = await gaitrig.api("/api/calibration/live-check");
    if (lastSeq.current(n)) render(j);
  }
  btn.addEventListener("click", async () => {
    lastSeq.acted();
    btn.disabled = true; state.className = ""; state.textContent = "Capturing fresh frames from every sensor…";
    try {
      const j0 = await gaitrig.api("/api/calibration/live-check", { method: "POST", body: JSON.stringify({ frames: 5 }) });
      for (;;) {
        const j = await gaitrig.api(`/api/calibration/captures/${j0.id}`);
        if (j.state !== "capturing" && j.state !== "computing") break;
        await gaitrig.wait(700);
      }
      await last();
    } catch (e) {
      state.className = "warn"; state.textContent = String(e.message || e);
    } finally { gaitrig.release(btn); }
  });
  // Before the first calibration the check has nothing to compare with: the button was
  // offered all the same and answered with the server's refusal. Say what to do first.
  async function firstLook() {
    const saved = await gaitrig.api("/api/calibration");
    if (Array.isArray(saved) && !saved.length) {
      lastSeq.acted();
      btn.disabled = true;
      state.className = "";
      state.replaceChildren("No calibration yet: the check compares the sensors with one. Calibrate first with the ",
        gaitrig.el("a", { href: "/calibration-wizard.html" }, "spatial calibration wizard"), ".");
      return;
    }
    await last();
  }
  firstLook().catch((e) => { state.textContent = String(e.message || e); });
})();
