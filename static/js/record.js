// Record page: pick (or create) project / subject / session, start and stop a recording
// on every connected sensor, watch the elapsed time, each sensor's part and, after the
// stop, the verified transfer to the server until the recording is complete.
"use strict";
(() => {
  const api = gaitrig.api;
  const $ = (id) => document.getElementById(id);
  const el = gaitrig.el;
  // a live region rewritten with the same text is read out again: only changes are written
  function sayOnce(node, text) { if (node.textContent !== text) node.textContent = text; }
  function say(id, text, good = false) { const m = $(id); m.textContent = text; m.className = "msg " + (good ? "good" : "bad"); }
  const STATE_TEXT = { recording: "recording", on_nodes: "on the sensors, waiting for transfer", transferring: "transferring to the server",
    complete: "complete — every part verified on the server", incomplete: "incomplete", on_node: "on the node", pending: "starting" };
  const PART_TEXT = { ...STATE_TEXT, complete: "complete", on_nodes: "on the sensors" };
  // A recording shorter than this (s) holds no step a report can use: the analysis needs
  // a straight pass and leaves out its first step and stride (a Stop pressed at once gave
  // a 0.1 s recording that the page called complete, and the report left out with "no
  // tracked AnkleLeft positions").
  const SHORT_WALK_S = 2;
  const mb = (n) => n >= 2 ** 20 ? (n / 2 ** 20).toFixed(1) + " MB" : (n / 1024).toFixed(0) + " kB";

  let recId = null, recStart = null, recStop = null, subjectId = null;

  const listPage = gaitrig.listPage;
  const SUBJECTS_SHOWN = 50;  // a clinic's thousands are found by typing part of the code

  async function fillProjects(want) {
    const ps = await api("/api/projects");
    const sel = $("project");
    sel.replaceChildren(...ps.map((p) => el("option", { value: p.id }, p.name)));
    if (!ps.length) {
      const p = await api("/api/projects", { method: "POST", body: JSON.stringify({ name: "Default project" }) });
      sel.append(el("option", { value: p.id }, p.name));
    }
    if (want) sel.value = want;
    await fillSubjects();
  }
  // The page's first lists can be answered after the user added a subject or a session
  // (or lists overlap after quick changes): an answer older than the newest asked is
  // dropped, else it would replace the list just drawn (the new subject gone from it).
  const subjectsSeq = gaitrig.latest(), sessionsSeq = gaitrig.latest();
  async function fillSubjects(want) {
    const mine = subjectsSeq.ask();
    const pid = Number($("project").value), q = $("subject-q").value.trim();
    let { items: ss, total } = q
      ? await listPage("/api/subjects/search", { q, project_id: pid, limit: SUBJECTS_SHOWN, bytes_on_server: false })
      : await listPage(`/api/subjects?project_id=${pid}&sort=-created&limit=${SUBJECTS_SHOWN}&bytes_on_server=false`);
    // the subject asked for (just added, or from the address) is offered even when the
    // search or the page does not show it
    if (want && !ss.some((s) => s.id === Number(want))) {
      try { const s = await api(`/api/subjects/${want}`); if (s.project_id === pid) { ss = [s, ...ss]; total += 1; } } catch (e) { /* gone */ }
    }
    if (!subjectsSeq.current(mine)) return;
    const sel = $("subject");
    sel.replaceChildren(...ss.map((s) => el("option", { value: s.id }, s.code)));
    if (!ss.length) sel.append(el("option", { value: "" }, q ? `— no code contains “${q}” —` : "— add a subject —"));
    $("subject-count").textContent = total > ss.length
      ? `${ss.length} of ${total} subjects shown${q ? "" : " (the newest)"}: type part of the code to find another.`
      : (q && ss.length ? `${ss.length} subject${ss.length === 1 ? "" : "s"} with “${q}” in the code.` : "");
    if (want) sel.value = want;
    await fillSessions();
  }
  async function fillSessions(want) {
    const mine = sessionsSeq.ask();
    const sel = $("session");
    subjectId = $("subject").value ? Number($("subject").value) : null;
    if (subjectId === null) { sel.replaceChildren(el("option", { value: "" }, "— add a subject first —")); showWhole(); return; }
    const ss = await api(`/api/sessions?subject_id=${subjectId}`);
    if (!sessionsSeq.current(mine)) return;
    // the count before the label: a long label is cut at its end, never the count
    // ("(2 recording…" at 1366 px); the whole text in the option's tooltip
    sel.replaceChildren(...ss.slice().reverse().map((s) => {
      const text = `${gaitrig.day(s.date)} (${gaitrig.plural(s.n_recordings, "recording")})${s.label ? " — " + s.label : ""}`;
      return el("option", { value: s.id, "data-recordings": String(s.n_recordings), title: text }, text);
    }));
    if (!ss.length) sel.append(el("option", { value: "" }, "— add a session —"));
    if (want) sel.value = want;
    suggestLabel();
    showWhole();
  }
  // The chosen subject's and session's text, whole, under a list too narrow to show it
  // (a phone, a zoomed window, a long session label): gaitrig.showWhole
  function showWhole() { gaitrig.showWhole(["subject", "session"]); }
  addEventListener("resize", showWhole);

  // A trial without a label is listed by its id ("R20261125-035820-9256") on the Subjects
  // and Reports pages, and the placeholder "walk 1" looked filled in but was not sent. The
  // field holds the next walk of the session ("walk 3" after two) until it is typed in, and
  // a label ending in a number counts on by itself after each recording.
  let labelTyped = false;
  $("label").addEventListener("input", () => { labelTyped = $("label").value.trim() !== ""; });
  function suggestLabel() {
    // (not while a recording runs: its own label stays in view until it stops)
    if (labelTyped || !$("stop").disabled) return;
    const o = $("session").selectedOptions[0];
    const n = o && o.dataset.recordings !== undefined ? Number(o.dataset.recordings) : 0;
    $("label").value = `walk ${n + 1}`;
  }
  function nextLabel(used) {
    const m = /^(.*?)(\d+)$/.exec(used);
    if (m && $("label").value.trim() === used) $("label").value = m[1] + String(Number(m[2]) + 1);
  }

  $("project").addEventListener("change", () => fillSubjects());
  $("subject").addEventListener("change", () => fillSessions());
  $("session").addEventListener("change", suggestLabel);
  $("session").addEventListener("change", showWhole);
  let typing = null;
  $("subject-q").addEventListener("input", () => {
    clearTimeout(typing);
    typing = setTimeout(() => fillSubjects().catch((e) => say("who-msg", e.message)), 250);
  });
  $("subject-q").addEventListener("keydown", (ev) => {
    if (ev.key !== "Enter") return;
    ev.preventDefault(); clearTimeout(typing);
    fillSubjects().then(() => $("subject").focus()).catch((e) => say("who-msg", e.message));
  });
  $("new-subject").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    try {
      const s = await api("/api/subjects", { method: "POST", body: JSON.stringify({ project_id: Number($("project").value), code: ev.target.elements.code.value.trim() }) });
      ev.target.reset(); await fillSubjects(s.id); say("who-msg", `Subject ${s.code} added; now add a session.`, true);
    } catch (e) { say("who-msg", e.message); }
  });
  $("new-session").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    if (subjectId === null) { say("who-msg", "Choose or add a subject first."); return; }
    try {
      const s = await api("/api/sessions", { method: "POST", body: JSON.stringify({ subject_id: subjectId, label: ev.target.elements.label.value.trim() }) });
      ev.target.reset(); await fillSessions(s.id); say("who-msg", "Session added.", true);
    } catch (e) { say("who-msg", e.message); }
  });

  async function refreshNodes() {
    try {
      const ns = await api("/api/nodes");
      const ready = ns.filter((n) => n.connected && n.clock_offset_ms !== null);
      sayOnce($("nodes-summary"), ns.length
        ? `${ready.length} of ${ns.length} sensors ready to record (${ready.map((n) => n.id).join(", ") || "none"}).`
        : "No sensor has connected yet; start the nodes (see the Rig page).");
    } catch (e) { sayOnce($("nodes-summary"), "The sensor list is not up to date: " + e.message); }
  }

  function fmtTime(s) { const m = Math.floor(s / 60); return `${m}:${(s - m * 60).toFixed(1).padStart(4, "0")}`; }
  function tick() {
    if (recStart !== null) $("elapsed").textContent = fmtTime(Math.max(0, (recStop ?? Date.now() / 1000) - recStart));
  }

  // What happened to a part besides its state, from the filed part `p` and the server's
  // live one `lp` (which keeps the reason of a part that ended complete: a node that
  // reconnected and kept recording, a part recovered after a crash). An error only while
  // the part is incomplete, else a note; a failed transfer is no news once the part is
  // transferring again or complete.
  function partWhy(p, lp) {
    const out = [];
    let reason = p.reason || (lp && lp.reason) || "";
    if (p.state !== "incomplete") reason = reason.split("; transfer failed")[0].replace(/^transfer failed.*/, "");
    if (reason) out.push(el("div", { class: p.state === "incomplete" ? "reason" : "note", "data-kind": "reason" }, reason));
    const skipped = p.images_skipped ?? (lp ? lp.images_skipped : null);
    if (skipped > 0)
      out.push(el("div", { class: "note", "data-kind": "images-skipped" },
        `${skipped} frame${skipped === 1 ? "" : "s"} recorded without ${skipped === 1 ? "its" : "their"} images: the sensor's image encoder fell behind (record images of every N-th frame with a larger N).`));
    return out;
  }

  function partRow(p, lp) {
    const prog = el("progress", { max: "1", value: String(p.progress), "aria-label": `transfer of ${p.node_id}` });
    return el("tr", { "data-node": p.node_id, "data-state": p.state },
      el("th", { scope: "row" }, p.node_id), el("td", {}, el("span", { class: "badge st-" + p.state }, PART_TEXT[p.state] || p.state)),
      el("td", { class: "num" }, String(p.n_frames)),
      el("td", { class: "num" }, prog, " ",
        el("span", { class: "amount" }, `${Math.round(p.progress * 100)}\u00a0% of ${mb(p.bytes_total)}`)),
      el("td", { class: "why" }, ...partWhy(p, lp)));
  }

  // The server's own view of the recording (GET /api/recordings/{id}) says what the filed
  // one does not: that it cannot save its recording list (disk full) and which sensors
  // are not in the recording. null: not known there (deleted meanwhile).
  function showLive(live) {
    const err = live ? live.save_error : null;
    $("save-error").hidden = !err;
    $("save-error").textContent = err ? `${err[0].toUpperCase()}${err.slice(1)}. Free space on the server's disk (the Subjects page shows how much is free); the list is saved again with the next change.` : "";
    const out = (live && live.not_in_recording) || [];
    $("left-out").hidden = !out.length;
    $("left-out").replaceChildren(...out.map((n) => el("li", { "data-node": n.node_id }, `${n.node_id} is not in this recording: ${n.reason}.`)));
  }

  // follow() starts a new chain of polls of the recording on the page; an older chain
  // ends (its answer would draw the previous recording over the new one, and two chains
  // would poll twice as often).
  const chain = gaitrig.latest();
  function follow() { poll(chain.ask()); }
  let copying = null;  // id of the recording stopped here, until its copy is complete
  let usedLabel = "";  // the trial label of the recording started here
  async function poll(mine) {
    if (!chain.current(mine) || recId === null) return;
    try {
      const [r, live] = await Promise.all([api(`/api/storage/recordings/${recId}`),
        api(`/api/recordings/${recId}`).catch(() => null)]);
      if (!chain.current(mine)) return;
      recStart = r.t_start; recStop = r.t_stop; tick();  // the time agrees with the state drawn
      const badge = $("state-badge");  // (redrawn only when it changed: a live region)
      if (!badge || badge.dataset.state !== r.state || badge.dataset.reason !== (r.reason || ""))
        $("rec-state").replaceChildren(el("span", { class: "badge st-" + r.state, id: "state-badge", "data-state": r.state, "data-reason": r.reason || "" }, STATE_TEXT[r.state] || r.state),
          r.reason ? el("span", { class: "reason" }, " " + r.reason) : "");
      const lparts = new Map((live ? live.parts : []).map((p) => [p.node_id, p]));
      $("parts").replaceChildren(...r.parts.map((p) => partRow(p, lparts.get(p.node_id))));
      $("parts-table").hidden = false;  // (headings over nothing before the first recording)
      showLive(live);
      const running = r.state === "recording";
      $("start").disabled = running; $("stop").disabled = !running;
      if (!running) {
        $("done-link").hidden = false;
        $("open-subject").href = `/subjects.html#subject=${r.subject.id}`;
      }
      // the stop's "now copies…" would otherwise stay beside the "complete" badge, and in
      // green beside an "incomplete" one (a Stop pressed at once: no sensor had a frame)
      if (copying === r.id && (r.state === "complete" || r.state === "incomplete")) {
        const shown = r.duration_s === null ? null : r.duration_s.toFixed(1);
        const short = shown !== null && Number(shown) < SHORT_WALK_S;  // (rounded as shown: never "only 2.0 s")
        const again = `it lasted only ${shown} s: too short for a gait report, which needs several steps of walking. Record the walk again (this recording can be deleted on Subjects & recordings).`;
        if (r.state === "complete") {
          copying = null;
          if (short) say("rec-msg", `Recording ${r.id} is copied to the server, but ${again}`);
          else say("rec-msg", `Recording ${r.id} is copied to the server: every sensor's part verified.`, true);
        } else {
          // (still followed: a transfer tried again later can complete it)
          const text = `Recording ${r.id} is incomplete: ${short ? again : "each sensor's note below says why."}`;
          if ($("rec-msg").textContent !== text) say("rec-msg", text);  // (a live region: once)
        }
      }
      // a save error stays on screen until the server saved again
      // (gaitrig.wait: the next poll not while the page is hidden, at once when shown)
      if (r.state !== "complete") gaitrig.wait(running ? 500 : 700).then(() => poll(mine));
      else if (live && live.save_error) gaitrig.wait(2000).then(() => poll(mine));
    } catch (e) { if (chain.current(mine)) { say("rec-msg", e.message); gaitrig.wait(2000).then(() => poll(mine)); } }
  }

  // The image interval means something only when images are recorded: it was offered
  // (and its value checked) with no images ticked.
  function everyField() { $("every-field").hidden = !($("depth").checked || $("color").checked); }
  for (const s of ["depth", "color"]) $(s).addEventListener("change", everyField);
  everyField();  // (a browser that restores the ticks of a reloaded page)

  $("start").addEventListener("click", async () => {
    const sid = $("session").value;
    if (!sid) { say("rec-msg", "Choose a subject and a session first (or add them under “Who and when”)."); return; }
    const streams = ["depth", "color"].filter((s) => $(s).checked);
    // checked here: the server's refusal named its field ("image_every: Input should be…")
    if (streams.length && !$("every").checkValidity()) {
      say("rec-msg", "Images of every N-th frame: enter a whole number from 1 to 1000.");
      $("every").focus();
      return;
    }
    $("start").disabled = true;
    try {
      const r = await api(`/api/sessions/${sid}/recordings`, { method: "POST", body: JSON.stringify({
        label: $("label").value.trim(), streams, image_every: streams.length ? Number($("every").value) || 1 : 1 }) });
      recId = r.id; recStart = r.t_start; recStop = null; $("done-link").hidden = true;
      // the last recording's time stayed until the next tick: a Stop pressed on it ended
      // the new recording before its start time, with no frame
      tick();
      usedLabel = $("label").value.trim();
      showLive(r);
      // the focus on Stop (Start is disabled), then the message in the live region: Stop is
      // read as the focus, the message once after it (written first, a reader could cut it
      // short with the focus's words)
      $("stop").disabled = false; $("stop").focus();
      say("rec-msg", `Recording ${r.id} started on ${r.parts.map((p) => p.node_id).join(", ")}.`, true);
      follow();
      fillSessions(sid).catch(() => {});  // the session's recording count went up
    } catch (e) { say("rec-msg", e.message); gaitrig.release($("start")); }
  });
  $("stop").addEventListener("click", async () => {
    $("stop").disabled = true;
    // a poll answered while the stop is on its way still says "recording" and would enable
    // Stop again (a second press: "not recording" under the stop's own message)
    chain.acted();
    try {
      await api(`/api/recordings/${recId}/stop`, { method: "POST" });
      // The disabled Stop dropped the keyboard focus to the page. It goes to the table of
      // this recording's sensors, right under Stop, where the copy to the server shows and
      // from which Tab leads to "Open this recording" (not to Start: a second press of the
      // key would start a new recording). Not to the message: a live region that is also
      // focused is read twice. So the focus first ("Sensors of this recording, table"),
      // then the message, read once after it.
      $("parts-table").hidden = false;  // (shown by the first poll; Stop may come before it)
      $("parts-table").focus();
      say("rec-msg", `Recording ${recId} stopped; the server now copies every sensor's part.`, true);
      copying = recId;
      nextLabel(usedLabel);  // the next walk's label is ready
      follow();  // an answer asked for before the stop would enable Stop again
    }
    catch (e) { say("rec-msg", e.message); gaitrig.release($("stop")); follow(); }
  });

  // A recording that was running when the page was opened (reloaded mid-walk, or opened
  // in a second tab): "Who and when" showed the newest subject and the label field the
  // session's next trial ("walk 3"), so the page said that someone else's walk was being
  // recorded, under another label. It shows the recording's own subject, session and
  // label, and says which recording Stop ends.
  async function showRunning(r) {
    recId = r.id;
    if (r.subject) {
      try {
        await fillProjects(r.subject.project_id);
        await fillSubjects(r.subject.id);
        await fillSessions(r.session_id);
      } catch (e) { say("who-msg", e.message); }
    }
    $("label").value = r.label || "";
    usedLabel = r.label || "";  // Stop counts it on ("walk 2" → "walk 3") as after a Start here
    const whose = r.subject ? ` of ${r.subject.code}` : "";
    say("rec-msg", `Recording ${r.id}${r.label ? ` (“${r.label}”)` : ""}${whose} is running: Stop ends it.`, true);
    follow();
  }

  (async () => {
    const m = /subject=(\d+)/.exec(location.hash);
    try {
      if (m) { const s = await api(`/api/subjects/${m[1]}`); await fillProjects(s.project_id); await fillSubjects(s.id); }
      else await fillProjects();
    } catch (e) { say("who-msg", e.message); }
    // A recording already running (started before this page was opened) is followed.
    try {
      // (the newest page: a running recording is the newest)
      const live = (await api("/api/recordings")).find((r) => r.state === "recording");
      if (live) {
        let r = null;
        try { r = await api(`/api/storage/recordings/${live.id}`); }
        catch (e) { say("rec-msg", `Recording ${live.id} is running (started elsewhere, not filed under a session).`); }
        if (r) await showRunning(r);
      }
    } catch (e) { /* the list is optional */ }
    refreshNodes(); gaitrig.poll(refreshNodes, 2000); setInterval(tick, 100);
  })();
})();
