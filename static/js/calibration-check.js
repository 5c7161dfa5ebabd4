// Calibrate page: bumped-tripod warning from the live check (re-detects the markers in
// fresh frames of every connected sensor and compares with the active calibration).
"use strict";
(() => {
  const state = document.getElementById("bump-state");
  const btn = document.getElementById("bump-check");
  if (!state || !btn) return;
  function render(j) {
    if (!j.checked) {
      state.className = ""; state.textContent = "No live check yet: run one after moving people or equipment near the sensors.";
      return;
    }
    const when = new Date(j.created * 1000).toLocaleTimeString();
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
  async function last() { render(await gaitrig.api("/api/calibration/live-check")); }
  btn.addEventListener("click", async () => {
    btn.disabled = true; state.className = ""; state.textContent = "Capturing fresh frames from every sensor…";
    try {
      const j0 = await gaitrig.api("/api/calibration/live-check", { method: "POST", body: JSON.stringify({ frames: 5 }) });
      for (;;) {
        const j = await gaitrig.api(`/api/calibration/captures/${j0.id}`);
        if (j.state !== "capturing" && j.state !== "computing") break;
        await new Promise((r) => setTimeout(r, 700));
      }
      await last();
    } catch (e) {
      state.className = "warn"; state.textContent = String(e.message || e);
    } finally { btn.disabled = false; }
  });
  last().catch((e) => { state.textContent = String(e.message || e); });
})();
