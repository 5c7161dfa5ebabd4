// Calibrate page: the sensor poses the rig reports and the planning tools (coverage map
// from /api/planning, moves through PUT /api/planning/sensors/{id}, save, placement sheet).
"use strict";
(() => {
  const el = gaitrig.el;
  const $ = (id) => document.getElementById(id);
  let plan = null;
  const f2 = (v) => v.toFixed(2);

  function poseOf(T) {
    const f = [T[0][2], T[1][2], T[2][2]];
    return { x: T[0][3], y: T[1][3], z: T[2][3], yaw: Math.atan2(f[1], f[0]) * 180 / Math.PI,
      pitch: Math.asin(Math.max(-1, Math.min(1, f[2]))) * 180 / Math.PI };
  }

  // One line across the table while it loads, when there is nothing to show, or when it
  // failed (an empty table under its headings looked like a page still loading, forever).
  const posesLine = (text) => $("poses").replaceChildren(el("tr", {}, el("td", { colspan: "7", class: "hint", role: "status" }, text)));
  async function loadPoses() {
    let nodes, sensors;
    try {
      nodes = await gaitrig.api("/api/nodes");
      sensors = await Promise.all(nodes.map((n) => gaitrig.api(`/api/nodes/${encodeURIComponent(n.id)}/sensor`)));
    } catch (e) { posesLine("The sensor poses could not be loaded: " + e.message); throw e; }
    if (!nodes.length) { posesLine("No sensor has connected yet: start the nodes (see the Rig page)."); return; }
    // the whole table at once: row by row, a slow server showed a table missing sensors
    $("poses").replaceChildren(...nodes.map((n, i) => {
      const s = sensors[i];
      const st = n.connected ? el("span", { class: "ok" }, "online") : el("span", { class: "off" }, "offline");
      if (!s.T_world_sensor) {
        return el("tr", {}, el("th", { scope: "row" }, n.id), el("td", {}, st),
          el("td", { colspan: "5" }, "pose unknown: calibrate this sensor"));
      }
      const p = poseOf(s.T_world_sensor);
      return el("tr", { "data-node": n.id }, el("th", { scope: "row" }, n.id), el("td", {}, st),
        ...[f2(p.x), f2(p.y), f2(p.z), p.yaw.toFixed(1), p.pitch.toFixed(1)].map((t) => el("td", { class: "num" }, t)));
    }));
  }

  // The plan is polled (the 3D view's drag handles change it too) while the user moves
  // sensors here: planSeq drops a poll answered after a newer plan was shown, and the
  // form keeps what the user is typing.
  const planSeq = gaitrig.newest();
  let editing = false;

  function showPlan(p) {
    plan = p;
    // (said "the wizard is not part of this console yet", under a link to the wizard)
    $("pose-source").textContent = `Poses shown: ${p.source}. The planner starts from these poses; ` +
      "measure the real ones with the spatial calibration wizard (link above).";
    $("coverage").src = `/api/planning/coverage.png?v=${p.version}&t=${Date.now()}`;
    $("coverage-stats").textContent = `Walkway seen whole by at least one sensor: ${(100 * p.walkway_covered_fraction).toFixed(0)} %; ` +
      `from both sides: ${(100 * p.walkway_two_sided_fraction).toFixed(0)} %. Whole map: ${(100 * p.covered_fraction).toFixed(0)} % covered.`;
    $("coverage").dataset.version = String(p.version);
    const legend = $("legend");
    legend.replaceChildren(...p.legend.map((l) => el("li", {},
      el("span", { class: "swatch", style: `background:rgb(${l.rgb.join(",")})` }), " " + l.label)));
    const sel = $("move-id"), cur = sel.value;
    sel.replaceChildren(...p.sensors.map((s) => el("option", { value: s.id }, s.id)));
    if (cur && p.sensors.some((s) => s.id === cur)) sel.value = cur;
    if (!editing) fillForm();
    $("planned").replaceChildren(...p.sensors.map((s) => el("tr", { class: s.moved ? "moved" : "", "data-node": s.id },
      el("th", { scope: "row" }, s.id + (s.moved ? " (moved)" : "")),
      ...[f2(s.position[0]), f2(s.position[1]), f2(s.position[2]), s.yaw_deg.toFixed(1), s.pitch_deg.toFixed(1)]
        .map((t) => el("td", { class: "num" }, t)))));
  }

  function fillForm() {
    const s = plan && plan.sensors.find((x) => x.id === $("move-id").value);
    if (!s) return;
    editing = false;
    $("move-x").value = f2(s.position[0]); $("move-y").value = f2(s.position[1]);
    $("move-z").value = f2(s.position[2]); $("move-yaw").value = s.yaw_deg.toFixed(0);
    $("move-pitch").value = s.pitch_deg.toFixed(0);
  }

  async function guarded(fn) {
    $("plan-error").textContent = ""; $("move-status").textContent = "";
    try { await fn(); } catch (e) { $("plan-error").textContent = e.message; }
  }

  // the user's own change: shown, and older poll answers dropped
  function changed(p) { planSeq.acted(); editing = false; showPlan(p); }
  async function fetchPlan() {
    const n = planSeq.ask();
    const p = await gaitrig.api("/api/planning");
    if (planSeq.fresh(n) && (!plan || p.version !== plan.version)) showPlan(p);
  }

  function init() {
    $("move-id").addEventListener("change", fillForm);
    for (const id of ["move-x", "move-y", "move-z", "move-yaw", "move-pitch"]) $(id).addEventListener("input", () => { editing = true; });
    $("move-form").addEventListener("submit", (ev) => {
      ev.preventDefault();
      guarded(async () => {
        const id = $("move-id").value;
        changed(await gaitrig.api(`/api/planning/sensors/${encodeURIComponent(id)}`, { method: "PUT",
          body: JSON.stringify({ position: [+$("move-x").value, +$("move-y").value, +$("move-z").value],
            yaw_deg: +$("move-yaw").value, pitch_deg: +$("move-pitch").value }) }));
        // (Apply with the values unchanged showed nothing at all: was it taken?)
        const s = plan.sensors.find((x) => x.id === id);
        if (s) $("move-status").textContent = `${id} planned at x ${f2(s.position[0])} m, y ${f2(s.position[1])} m, ` +
          `height ${f2(s.position[2])} m, yaw ${s.yaw_deg.toFixed(0)}°, pitch ${s.pitch_deg.toFixed(0)}°; the map shows its coverage.`;
      });
    });
    $("plan-reset").addEventListener("click", () => guarded(async () => {
      changed(await gaitrig.api("/api/planning/reset", { method: "POST" }));
      $("move-status").textContent = "The plan is the rig's current sensor poses again.";
    }));
    $("save-form").addEventListener("submit", (ev) => {
      ev.preventDefault();
      guarded(async () => {
        const r = await gaitrig.api("/api/planning/save", { method: "POST", body: JSON.stringify({ name: $("save-name").value }) });
        $("save-status").textContent = `Saved ${r.file} (${r.bytes} bytes) in the server's data folder.`;
      });
    });
    guarded(() => Promise.all([loadPoses(), fetchPlan()]));
    // the 3D view's drag handles change the plan too: follow them (a failed poll says so,
    // a good one leaves the message of the user's last action in place)
    gaitrig.poll(() => fetchPlan().catch((e) => { $("plan-error").textContent = e.message; }), 1500);
  }
  init();
})();
