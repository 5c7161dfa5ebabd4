// Reports page: subject/session report (inline HTML fragment + PDF link), one- vs
// two-sided comparison of a recording's sensor subsets, reference upload (one recording's,
// or many at once), a project's agreement with a reference system (HTML fragment, PDF,
// CSV), file analysis.
"use strict";
(() => {
  const $ = (id) => document.getElementById(id);
  const el = gaitrig.el;
  const plural = gaitrig.plural;

  // fetch without the JSON content type (multipart uploads, HTML, PDF blobs)
  async function call(path, options = {}) {
    const r = await fetch(path, { credentials: "same-origin", ...options });
    if (r.status === 401) { gaitrig.toLogin(); throw new Error("not logged in"); }
    if (!r.ok) {
      let d = r.statusText;
      try { d = (await r.json()).detail || d; } catch (e) { /* not JSON */ }
      throw new Error(d);
    }
    return r;
  }
  const json = async (path, options) => (await call(path, options)).json();
  // A page of a list with how many match in all (the X-Total-Count header). With `body`,
  // a POST: a subject code searched for goes in the body, never in a URL (access logs).
  async function listPage(path, body) {
    const r = await call(path, body === undefined ? {} : { method: "POST", body: JSON.stringify(body),
      headers: { "Content-Type": "application/json" } });
    const items = await r.json();
    return { items, total: Number(r.headers.get("X-Total-Count") ?? items.length) };
  }
  const SHOWN = 100;  // a clinic's thousands are found by typing part of the code or id
  function countText(id, shown, total, q, what, field) {
    $(id).textContent = total > shown
      ? `${shown} of ${total} ${what} shown (the newest): type part of ${field} to find another.`
      : (q ? `${total} ${total === 1 ? what.replace(/s$/, "") : what} found.` : "");
  }
  function onSearch(input, run) {
    let typing = null;
    input.addEventListener("input", () => { clearTimeout(typing); typing = setTimeout(run, 250); });
    // Enter searches now (instead of submitting the report form around the field)
    input.addEventListener("keydown", (ev) => { if (ev.key === "Enter") { ev.preventDefault(); clearTimeout(typing); run(); } });
  }

  function say(id, text, isError = false) {
    const p = $(id);
    p.textContent = text;
    p.classList.toggle("error", isError);
  }

  // `help`: the guide's part that explains the report's notes
  function showReport(html, help = "/help.html#report-quality") {
    $("report").innerHTML = html; // server-rendered, escaped by the template engine
    // the data-quality notes (too few steps, one-sided, clock, calibration) are explained in the guide
    const notes = $("report").querySelector("ul.notes");
    if (notes) notes.after(el("p", { class: "hint" }, el("a", { href: help }, "What does this mean?")));
    $("report-section").hidden = false;
    // the focus on the report's title: a screen reader says which report this is
    // (the report's box alone has no name)
    const title = $("report").querySelector("h1");
    if (title) { title.tabIndex = -1; title.focus(); } else $("report").focus();
  }

  function hideReport() { $("report-section").hidden = true; $("report").replaceChildren(); }

  // PDF (or CSV) through fetch so that a refusal (e.g. no complete recording) shows as a
  // message on this page instead of a raw error document.
  async function downloadPdf(url, msgId, fallbackName, kind = "PDF") {
    say(msgId, kind === "PDF" ? "Rendering the PDF…" : `Computing the ${kind}…`);
    try {
      const r = await call(url);
      const cd = r.headers.get("Content-Disposition") || "";
      const m = /filename="([^"]+)"/.exec(cd);
      const blob = await r.blob();
      const a = el("a", { href: URL.createObjectURL(blob), download: m ? m[1] : fallbackName });
      document.body.append(a); a.click(); a.remove();
      setTimeout(() => URL.revokeObjectURL(a.href), 10000);
      say(msgId, `${kind} downloaded (${m ? m[1] : fallbackName}).`);
    } catch (e) { say(msgId, e.message, true); }
  }

  function setLink(a, href) {
    if (href) { a.href = href; a.removeAttribute("aria-disabled"); }
    else { a.href = "#"; a.setAttribute("aria-disabled", "true"); }
  }

  // ------------------------------------------------------------------ subject report
  let subjects = [];

  function subjectQuery(format) {
    const sid = $("subject").value;
    if (!sid) return null;
    const q = new URLSearchParams({ format, method: $("method").value,
      estimator: $("estimator").value });
    if ($("session").value) q.set("session_id", $("session").value);
    else {
      // the ticked sessions, when not all of them (none ticked: no report to ask for)
      const boxes = sessionBoxes(), ticked = boxes.filter((c) => c.checked).map((c) => c.value);
      if (boxes.length && !ticked.length) return null;
      if (ticked.length < boxes.length) q.set("sessions", ticked.join(","));
    }
    return `/api/reports/subjects/${encodeURIComponent(sid)}?${q}`;
  }
  function sessionBoxes() { return [...$("sessions-pick").querySelectorAll("input[type=checkbox]")]; }
  // the session checkboxes are offered for "All sessions" of a subject with two or more
  function showSessionPick() {
    $("sessions-pick").hidden = Boolean($("session").value) || sessionBoxes().length < 2;
  }

  const subjectsSeq = gaitrig.latest();
  async function loadSubjects() {
    const mine = subjectsSeq.ask();
    const q = $("subject-q").value.trim();
    let total;
    try {
      // (codes and counts only: the disk usage would read every listed subject's folders)
      ({ items: subjects, total } = q ? await listPage("/api/subjects/search", { q, sort: "code", limit: SHOWN, bytes_on_server: false })
        : await listPage(`/api/subjects?sort=-created&limit=${SHOWN}&bytes_on_server=false`));
    } catch (e) { say("subject-msg", "Cannot load subjects: " + e.message, true); return; }
    if (!subjectsSeq.current(mine)) return;
    const sel = $("subject"), was = sel.value;
    sel.replaceChildren(el("option", { value: "" }, subjects.length ? "Choose a subject…" : q ? `No subject code contains “${q}”` : "No subjects yet"));
    for (const s of subjects) {
      sel.append(el("option", { value: String(s.id) }, `${s.code} — ${plural(s.n_sessions, "session")}, ${plural(s.n_recordings, "recording")}`));
    }
    countText("subject-count", subjects.length, total, q, "subjects", "the code in “Find subject code”");
    // the subject of the address (a link #subject=ID, or the one chosen) stays offered
    const linked = /subject=(\d+)/.exec(location.hash);
    if (linked && !q) await offerSubject(linked[1]);
    if (!subjectsSeq.current(mine)) return;
    if (was && subjects.some((s) => String(s.id) === was)) sel.value = was;
    else if (subjects.length === 1 && !(linked && !q)) {
      // the only subject (on the server, or found by the search) is chosen for the user
      // (the list of one had to be opened, and "Show report" alone gave a browser bubble);
      // a link's subject is chosen by fromAddress
      sel.value = String(subjects[0].id);
      subjectChanged();
    } else if (was) subjectChanged();  // the chosen subject left the list
    showWhole();
    if (!total && !q) say("subject-msg", "Add a subject and record a walk on the Record page first.");
  }
  // the subject of a link (#subject=ID) is offered even when it is not among those listed
  async function offerSubject(sid) {
    if (subjects.some((s) => String(s.id) === sid)) return true;
    let s;
    try { s = await json(`/api/subjects/${encodeURIComponent(sid)}`); } catch (e) { return false; }
    subjects.push(s);
    $("subject").append(el("option", { value: String(s.id) }, `${s.code} — ${plural(s.n_sessions, "session")}, ${plural(s.n_recordings, "recording")}`));
    return true;
  }

  // Two drawings of the same subject can be under way at once (the page chooses the
  // only subject as it loads while the person chooses it too): only the last one asked
  // draws, else both added their sessions and every session was listed twice.
  const subjectSeq = gaitrig.latest();
  async function subjectChanged() {
    const asked = subjectSeq.ask();
    const sid = $("subject").value;
    const sess = $("session");
    sess.replaceChildren(el("option", { value: "" }, "All sessions"));
    const pickBox = $("sessions-pick").querySelector(".checks");
    pickBox.replaceChildren();
    showSessionPick();
    setLink($("pdf"), null);
    showWhole();
    if (!sid) return;
    try {
      const s = await json(`/api/subjects/${encodeURIComponent(sid)}`);
      if (!subjectSeq.current(asked)) return;  // chosen again meanwhile (or another one)
      for (const x of s.sessions || []) {
        const done = (x.recordings || []).filter((r) => r.state === "complete").length;
        // the count before the label (as on the Record page): a long label is cut at its
        // end, never the count; the whole text in the option's tooltip
        const text = `${gaitrig.day(x.date)} (${plural(done, "complete recording")})${x.label ? " — " + x.label : ""}`;
        sess.append(el("option", { value: String(x.id), title: text }, text));
        const cb = el("input", { type: "checkbox", id: `pick-session-${x.id}`, value: String(x.id) });
        cb.checked = true;
        cb.addEventListener("change", () => setLink($("pdf"), subjectQuery("pdf")));
        const lab = el("label", { for: cb.id });
        lab.append(cb, ` ${gaitrig.day(x.date)} ${x.label || ""}`);
        pickBox.append(lab);
      }
      showSessionPick();
      showWhole();
    } catch (e) { if (!subjectSeq.current(asked)) return; say("subject-msg", e.message, true); }
    setLink($("pdf"), subjectQuery("pdf"));
  }

  async function showSubject(ev) {
    ev.preventDefault();
    const url = subjectQuery("html");
    if (!url) {
      // the page's own message (the select is not `required`: the browser's bubble covered
      // "Show report" and was gone at the next click)
      say("subject-msg", $("subject").value ? "Tick at least one session to include." : "Choose a subject first.", true);
      if (!$("subject").value) $("subject").focus();
      return;
    }
    say("subject-msg", "Analysing the recordings… (a first analysis takes a few seconds)");
    $("show").disabled = true;
    try {
      const r = await call(url);
      showReport(await r.text());
      say("subject-msg", "Report below.");
    } catch (e) {
      hideReport();
      say("subject-msg", e.message, true);
    } finally { gaitrig.release($("show")); }
  }

  // ------------------------------------------------------------------ one vs two sided
  let sensors = [];

  function checks(set) { return [...$(set).querySelectorAll("input[type=checkbox]")]; }
  function chosen(set) { return checks(set).filter((c) => c.checked).map((c) => c.value); }
  function pick(set, ids) { for (const c of checks(set)) c.checked = ids.includes(c.value); updateRecLinks(); }

  function buildSubset(set, initial) {
    const box = $(set).querySelector(".checks");
    box.replaceChildren();
    // (two empty frames before a recording is chosen)
    if (!sensors.length) {
      box.append(el("span", { class: "hint" }, "Choose a recording above to list its sensors."));
      $(set).querySelector(".presets").replaceChildren();
      return;
    }
    for (const s of sensors) {
      const id = `${set}-${s.id}`;
      const cb = el("input", { type: "checkbox", id, value: s.id });
      cb.checked = initial.includes(s.id);
      cb.addEventListener("change", updateRecLinks);
      const lab = el("label", { for: id });
      lab.append(cb, ` ${s.id}${s.side ? ` (${s.side})` : ""}`);
      box.append(lab);
    }
    const presets = $(set).querySelector(".presets");
    presets.replaceChildren();
    const groups = [["All", sensors.map((s) => s.id)]];
    // which side is which, in words ("Side A only" did not say): left and right of a
    // person walking the walkway the way the 3D view looks (the server's sides)
    for (const side of ["left", "right"]) {
      const ids = sensors.filter((s) => s.side === side).map((s) => s.id);
      if (ids.length) groups.push([`${side === "left" ? "Left" : "Right"} side only (${ids.join(", ")})`, ids]);
    }
    for (const [label, ids] of groups) {
      const b = el("button", { type: "button", class: "secondary" }, label);
      b.addEventListener("click", () => pick(set, ids));
      presets.append(b);
    }
  }

  function recQuery(format) {
    const rid = $("recording").value;
    const a = chosen("set-a");
    if (!rid || !a.length) return null;
    const q = new URLSearchParams({ format, sensors: a.join(","), method: $("method").value,
      estimator: $("estimator").value });
    return `/api/reports/recordings/${encodeURIComponent(rid)}/report?${q}`;
  }
  function updateRecLinks() { setLink($("rec-pdf"), recQuery("pdf")); }

  const recordingsSeq = gaitrig.latest();
  async function loadRecordings() {
    const mine = recordingsSeq.ask();
    const q = $("recording-q").value.trim();
    let recs = [], total = 0;
    try { ({ items: recs, total } = await listPage(`/api/reports/recordings?limit=${SHOWN}${q ? "&q=" + encodeURIComponent(q) : ""}`)); }
    catch (e) { say("cmp-msg", e.message, true); return; }
    if (!recordingsSeq.current(mine)) return;
    countText("recording-count", recs.length, total, q, "recordings", "the trial label, session label or id in “Find recording”");
    const sel = $("recording"), was = sel.value;
    sel.replaceChildren(el("option", { value: "" }, recs.length ? "Choose a recording…" : q ? `No recording matches “${q}”` : "No recording on the server yet"));
    for (const r of recs) {
      const who = r.subject_code ? [r.subject_code, r.session_label, gaitrig.day(r.session_date)].filter(Boolean).join(", ") : "no subject";
      // the clinician's own trial label ("walk 2") first: ids alone told the walks apart
      // by their start time only; the id last, where a list too narrow cuts the text
      const text = `${r.label ? r.label + " — " : ""}${who} — ${plural(r.sensors.length, "sensor")} — ${r.id}`;
      sel.append(el("option", { value: r.id, title: text }, text));
    }
    if (was && recs.some((r) => r.id === was)) sel.value = was;
    else if (was) recordingChanged();  // the chosen recording left the list
    showWhole();
  }

  // The chosen entry's text, whole, under a list too narrow to show it (gaitrig.showWhole)
  function showWhole() { gaitrig.showWhole(["subject", "session", "recording", "study-project"]); }
  addEventListener("resize", showWhole);

  async function recordingChanged() {
    const rid = $("recording").value;
    showWhole();
    $("cmp-table").hidden = true;
    sensors = [];
    if (!rid) { buildSubset("set-a", []); buildSubset("set-b", []); updateRecLinks(); return; }
    let got;
    try { got = (await json(`/api/reports/recordings/${encodeURIComponent(rid)}/sensors`)).sensors; }
    catch (e) { if ($("recording").value === rid) say("cmp-msg", e.message, true); return; }
    // another recording chosen meanwhile: its own answer draws the subsets
    if ($("recording").value !== rid) return;
    sensors = got;
    // subset A: the side of the first sensor (S1's side in the usual avenue)
    const first = sensors.find((s) => s.side);
    const side = first ? first.side : "";
    const sideA = sensors.filter((s) => side && s.side === side).map((s) => s.id);
    buildSubset("set-a", sideA.length ? sideA : sensors.slice(0, 1).map((s) => s.id));
    buildSubset("set-b", sensors.map((s) => s.id));
    say("cmp-msg", sideA.length ? `Subset A: the sensors on the ${side} of the walkway (${sideA.join(", ")}); B: all sensors. ` +
      "Left and right as seen walking along the walkway the way the 3D view looks." : "");
    updateRecLinks();
    refreshReference();
  }

  // a subset in words: "left side (S1, S3, S5)", "all sensors", else its ids
  function subsetName(ids) {
    const same = (xs) => xs.length === ids.length && xs.every((x) => ids.includes(x));
    if (same(sensors.map((s) => s.id))) return `all sensors (${ids.join(", ")})`;
    for (const side of ["left", "right"]) {
      if (same(sensors.filter((s) => s.side === side).map((s) => s.id))) return `${side} side (${ids.join(", ")})`;
    }
    return ids.join(", ");
  }

  const ms = (p, scale, d) => (!p || p.mean === null ? "—"
    : `${(scale * p.mean).toFixed(d)} ± ${p.sd === null ? "—" : (scale * p.sd).toFixed(d)}`);

  function cmpRows(a, b) {
    const sa = a.ok ? a.gait.summary : null, sb = b.ok ? b.gait.summary : null;
    const num = (s, f) => (s ? f(s) : null);
    const rows = [
      ["Sensors", a.sensors_used.join(", "), b.sensors_used.join(", "), null],
      // (was "Sensors per joint sample": the fusion's term)
      ["Sensors seeing each joint (average)", a.fusion ? a.fusion.sensors_per_sample.toFixed(2) : "—",
        b.fusion ? b.fusion.sensors_per_sample.toFixed(2) : "—", null],
      ["Steps analysed", num(sa, (s) => String(s.n_steps)) || "—", num(sb, (s) => String(s.n_steps)) || "—", null],
    ];
    const params = [
      ["Walking speed (m/s)", (s) => s.walking_speed_m_s, 1, 2, false],
      ["Cadence (steps/min)", (s) => s.cadence_steps_min, 1, 1, false],
      ["Step length (cm)", (s) => s.step_length_m, 100, 1, true],
      ["Step width (cm)", (s) => s.step_width_m, 100, 1, true],
      ["Step time (s)", (s) => s.step_time_s, 1, 3, true],
      ["Stride length (cm)", (s) => s.stride_length_m, 100, 1, true],
    ];
    for (const [label, get, scale, d, hasSd] of params) {
      const pa = sa ? get(sa) : null, pb = sb ? get(sb) : null;
      const mean = (p) => (p === null || p === undefined ? null : hasSd ? p.mean : p);
      const txt = (p) => (p === null || p === undefined ? "—" : hasSd ? ms(p, scale, d) : (scale * p).toFixed(d));
      const diff = mean(pa) !== null && mean(pb) !== null ? (scale * (mean(pb) - mean(pa))).toFixed(d) : "—";
      rows.push([label, txt(pa), txt(pb), diff]);
    }
    return rows;
  }

  async function compare() {
    const rid = $("recording").value;
    const a = chosen("set-a"), b = chosen("set-b");
    if (!rid) { say("cmp-msg", "Choose a recording first.", true); return; }
    if (!a.length || !b.length) { say("cmp-msg", "Tick at least one sensor in each subset.", true); return; }
    say("cmp-msg", "Analysing both subsets…");
    $("compare").disabled = true;
    try {
      const q = new URLSearchParams({ a: a.join(","), b: b.join(","), method: $("method").value,
        estimator: $("estimator").value });
      const r = await json(`/api/reports/recordings/${encodeURIComponent(rid)}/compare?${q}`);
      // another recording chosen while this one was analysed: its numbers would be shown
      // under the new choice (the table names the sensors, not the recording)
      if ($("recording").value !== rid) return;
      const body = $("cmp-table").querySelector("tbody");
      body.replaceChildren();
      for (const [label, va, vb, d] of cmpRows(r.a, r.b)) {
        const tr = el("tr");
        tr.append(el("th", label.startsWith("Sensors seeing") ? { scope: "row", title: "sensors per joint sample, after fusion" } : { scope: "row" }, label), el("td", {}, va), el("td", {}, vb), el("td", {}, d === null ? "" : d));
        body.append(tr);
      }
      $("cmp-a-h").textContent = `A: ${subsetName(a)}`;
      $("cmp-b-h").textContent = `B: ${subsetName(b)}`;
      $("cmp-table").hidden = false;
      const errs = [r.a, r.b].filter((x) => !x.ok).map((x) => `${x.sensors_used.join(", ")}: ${x.error}`);
      say("cmp-msg", errs.length ? "No gait result for " + errs.join("; ") : "Mean ± SD per subset.", errs.length > 0);
    } catch (e) {
      if ($("recording").value === rid) say("cmp-msg", e.message, true);
    } finally { gaitrig.release($("compare")); }
  }

  async function recReport() {
    const url = recQuery("html");
    if (!url) { say("cmp-msg", "Choose a recording and at least one sensor in subset A.", true); return; }
    say("cmp-msg", "Building the report…");
    try {
      showReport(await (await call(url)).text());
      say("cmp-msg", "Report of subset A below.");
    } catch (e) { hideReport(); say("cmp-msg", e.message, true); }
  }

  // ------------------------------------------------------------------ reference
  async function refreshReference() {
    const rid = $("recording").value;
    if (!rid) { $("ref-state").textContent = ""; return; }
    try {
      const r = await json(`/api/reports/recordings/${encodeURIComponent(rid)}/reference`);
      // without one here, the newest attached on the Subjects page is the one used
      // (app/api/routes/reports.py, _reference_paths); named, so nobody has to guess
      let other = null;
      if (!r.attached) {
        try { const refs = await json(`/api/exports/${encodeURIComponent(rid)}/references`); other = refs.length ? refs[refs.length - 1] : null; }
        catch (e) { other = undefined; }  // (not known: said in general words)
      }
      if ($("recording").value !== rid) return;  // the newer choice's answer draws
      $("ref-state").textContent = r.attached
        ? `Attached: ${r.filename} (${r.n_steps} steps, starts ${r.offset_s} s into the recording). Reports use this one.`
        : other ? `None attached here: reports use ${other.filename}, attached on the Subjects page.`
        : other === null ? "None attached here or on the Subjects page: reports of this recording have no agreement section."
        : "None attached here: reports use the newest reference attached on the Subjects page, if any.";
      $("ref-remove").disabled = !r.attached;
    } catch (e) { if ($("recording").value === rid) $("ref-state").textContent = e.message; }
  }

  // Attach `file` as the reference of recording `rid`, starting `offset` s into it (the
  // server's answer; its refusal, which names the file, is thrown)
  function uploadReference(rid, file, offset) {
    const fd = new FormData();
    fd.append("file", file);
    const q = new URLSearchParams({ offset_s: offset });
    return json(`/api/reports/recordings/${encodeURIComponent(rid)}/reference?${q}`, { method: "POST", body: fd });
  }

  async function attachReference(ev) {
    ev.preventDefault();
    const rid = $("recording").value;
    const f = $("ref-file").files[0];
    if (!rid || !f) { say("ref-msg", "Choose a recording and a file.", true); return; }
    say("ref-msg", "Uploading and analysing the reference…");
    try {
      const r = await uploadReference(rid, f, $("ref-offset").value || "0");
      say("ref-msg", `Attached (${r.n_steps} reference steps). Reports of this recording now include an agreement section.`);
      refreshReference();
    } catch (e) {
      // as the Subjects page's "Attach reference" says it: the server's refusal names the
      // file ("'walk.trc' has no walk in it: …"), and the reference attached before stays
      say("ref-msg", e.message.includes(f.name) ? `Not attached: ${e.message}` : `${f.name} not attached: ${e.message}`, true);
    }
  }

  async function removeReference() {
    const rid = $("recording").value;
    if (!rid) return;
    try {
      await json(`/api/reports/recordings/${encodeURIComponent(rid)}/reference`, { method: "DELETE" });
      say("ref-msg", "Reference removed.");
      refreshReference();
    } catch (e) { say("ref-msg", e.message, true); }
  }

  // ------------------------------------------------------------------ agreement study
  async function loadProjects() {
    let projects;
    try { projects = await json("/api/projects?limit=1000"); }
    catch (e) { say("study-msg", "Cannot load projects: " + e.message, true); return; }
    const sel = $("study-project"), was = sel.value;
    sel.replaceChildren(el("option", { value: "" }, projects.length ? "Choose a project…" : "No projects yet"));
    for (const p of projects) {
      sel.append(el("option", { value: String(p.id) }, `${p.name} — ${plural(p.n_subjects, "subject")}`));
    }
    if (was && projects.some((p) => String(p.id) === was)) sel.value = was;
    else if (projects.length === 1) sel.value = String(projects[0].id);
    showWhole();
  }

  // the study's address, or null with the page's message said (no project chosen)
  function studyQuery(format) {
    const pid = $("study-project").value;
    if (!pid) {
      say("study-msg", "Choose a project first.", true);
      $("study-project").focus();
      return null;
    }
    const q = new URLSearchParams({ format, method: $("study-method").value,
      estimator: $("study-estimator").value });
    // the server checks the ids (and says which recording lacks one)
    const sensors = $("study-sensors").value.replace(/\s+/g, "");
    if (sensors) q.set("sensors", sensors);
    const reference = $("study-reference").value.trim();
    if (reference) q.set("reference_name", reference);
    return `/api/reports/projects/${encodeURIComponent(pid)}/agreement?${q}`;
  }

  async function showStudy(ev) {
    ev.preventDefault();
    const url = studyQuery("html");
    if (!url) return;
    say("study-msg", "Analysing the project's recordings and their references… (a first analysis takes a few seconds per recording)");
    $("study-show").disabled = true;
    try {
      const r = await call(url);
      showReport(await r.text(), "/help.html#report-study");
      say("study-msg", "Agreement below.");
    } catch (e) {
      hideReport();
      say("study-msg", e.message, true);
    } finally { gaitrig.release($("study-show")); }
  }

  // ------------------------------------------------------------------ references in bulk
  // "Attach references to several recordings": files of the chosen project's walks, each
  // matched to a recording by its name (or by a manifest chosen with them), attached one
  // after another through the one-recording upload (POST …/reference), so that a refused
  // file leaves the others attached and its recording's reference as it was.
  const SKIP = "-";  // "Leave this file out"
  let bulkRecs = [];  // the project's recordings (GET /api/reports/recordings of its subjects)
  let bulkRecsOf = null;  // the project they are of (null while they are listed)
  let bulkRows = [];
  let bulkManifest = null;  // normalised file name → {recording, subject, offset, line}
  let bulkBusy = false;
  const bulkSeq = gaitrig.latest();
  // lower case, letters and digits only: "P01_Walk-3" and "p01 walk 3" are the same
  const norm = (s) => String(s || "").toLowerCase().normalize("NFKD").replace(/[^\p{L}\p{N}]/gu, "");
  const stem = (name) => name.replace(/\.[^.]*$/, "");
  const isDigit = (c) => c !== undefined && c >= "0" && c <= "9";
  // `needle` in `hay`, not running on into digits: "walk1" is not in "walk10", "p01" not in "p012"
  function holds(hay, needle) {
    if (!needle) return false;
    for (let i = hay.indexOf(needle); i >= 0; i = hay.indexOf(needle, i + 1)) {
      if (isDigit(needle[0]) && isDigit(hay[i - 1])) continue;
      if (isDigit(needle[needle.length - 1]) && isDigit(hay[i + needle.length])) continue;
      return true;
    }
    return false;
  }
  // Of several recordings, those the file name also names the subject of (labels repeat
  // over subjects: "walk 3" of each), then those whose label no other one's contains
  // ("walk 1 slow" over "walk 1" for "P01 walk 1 slow.c3d").
  function narrow(cands, key) {
    if (cands.length > 1) {
      const bySubject = cands.filter((r) => r.subject_code && holds(key, norm(r.subject_code)));
      if (bySubject.length) cands = bySubject;
    }
    if (cands.length > 1) {
      cands = cands.filter((r) => !cands.some((o) => o !== r && norm(o.label) !== norm(r.label)
        && norm(o.label).includes(norm(r.label))));
    }
    return cands;
  }
  // The recording a file's name says (its code, else its trial label), or why none is chosen.
  function matchByName(name) {
    const key = norm(stem(name));
    const byId = bulkRecs.filter((r) => holds(key, norm(r.id)));
    const cands = byId.length ? byId : narrow(bulkRecs.filter((r) => r.label && holds(key, norm(r.label))), key);
    if (cands.length === 1) return { rec: cands[0] };
    return { why: cands.length ? `Its name fits ${cands.length} recordings (${cands.map(recName).join("; ")}): choose one.`
      : "No trial label or recording code of the project's recordings is in its name: choose its recording." };
  }
  function matchByManifest(m) {
    const want = norm(m.recording);
    let cands = bulkRecs.filter((r) => norm(r.id) === want);
    if (!cands.length) cands = bulkRecs.filter((r) => r.label && norm(r.label) === want);
    if (m.subject) cands = cands.filter((r) => norm(r.subject_code) === norm(m.subject));
    if (cands.length === 1) return { rec: cands[0] };
    const what = `The manifest's line ${m.line} (recording “${m.recording}”${m.subject ? `, subject “${m.subject}”` : ""})`;
    return { why: cands.length ? `${what} fits ${cands.length} recordings: add the subject column, or choose one.`
      : `${what} names no recording of the project: choose its recording.` };
  }
  const recName = (r) => [r.subject_code, r.label].filter(Boolean).join(" ") || r.id;
  function recText(r) {
    const who = [r.session_label, gaitrig.day(r.session_date)].filter(Boolean).join(", ");
    return `${recName(r)}${who ? " — " + who : ""} — ${r.id}`;
  }

  // one line of a CSV file (quoted cells with commas in them, "" for a quote)
  function csvCells(line) {
    const out = [];
    let cell = "", quoted = false;
    for (let i = 0; i < line.length; i++) {
      const c = line[i];
      if (quoted) {
        if (c === '"' && line[i + 1] === '"') { cell += '"'; i++; } else if (c === '"') quoted = false; else cell += c;
      } else if (c === '"') quoted = true;
      else if (c === ",") { out.push(cell.trim()); cell = ""; } else cell += c;
    }
    out.push(cell.trim());
    return out;
  }
  // A manifest (header recording,reference[,offset_s][,subject]; "file" for "reference"):
  // {rows} or {error}; null for a CSV that is not one (a skeleton CSV: a reference).
  function manifestOf(text) {
    const lines = text.replace(/^\uFEFF/, "").split(/\r?\n/);
    const head = csvCells(lines[0] || "").map((h) => h.toLowerCase());
    const col = (...names) => head.findIndex((h) => names.includes(h));
    const iRec = col("recording"), iFile = col("reference", "file"), iOff = col("offset_s"), iSub = col("subject");
    if (iRec < 0 || iFile < 0) return null;
    const rows = [];
    for (let n = 1; n < lines.length; n++) {
      const cells = csvCells(lines[n]);
      if (!cells.some(Boolean)) continue;
      const file = (cells[iFile] || "").split(/[\\/]/).pop(), recording = cells[iRec] || "";
      if (!file || !recording) return { error: `line ${n + 1}: no ${file ? "recording" : "reference file"} given` };
      let offset = "0";
      if (iOff >= 0 && cells[iOff]) {
        if (!Number.isFinite(Number(cells[iOff]))) return { error: `line ${n + 1}: offset_s “${cells[iOff]}” is not a number of seconds` };
        offset = cells[iOff];
      }
      rows.push({ file, recording, subject: iSub >= 0 ? cells[iSub] || "" : "", offset, line: n + 1 });
    }
    return rows.length ? { rows } : { error: "it lists no file: give one line recording,reference,offset_s a file under its header" };
  }

  async function bulkLoadRecordings() {
    const mine = bulkSeq.ask();
    const pid = $("study-project").value;
    bulkRecs = [];
    bulkRecsOf = null;
    if (pid) {
      try {
        const subjects = (await listPage(`/api/subjects?project_id=${encodeURIComponent(pid)}&limit=500&bytes_on_server=false`)).items;
        const lists = await Promise.all(subjects.map((s) =>
          listPage(`/api/reports/recordings?subject_id=${encodeURIComponent(s.id)}&limit=500`)));
        if (!bulkSeq.current(mine)) return;
        bulkRecs = lists.flatMap((l) => l.items);
        bulkRecs.sort((a, b) => (a.subject_code || "").localeCompare(b.subject_code || "")
          || (a.session_date || "").localeCompare(b.session_date || "")
          || (a.label || "").localeCompare(b.label || "", undefined, { numeric: true }) || a.created - b.created);
      } catch (e) { if (bulkSeq.current(mine)) say("bulk-msg", "Cannot list the project's recordings: " + e.message, true); return; }
    }
    if (!bulkSeq.current(mine)) return;
    bulkRecsOf = pid;
    bulkDraw();
  }

  async function bulkFilesChosen() {
    const files = [...$("bulk-files").files];
    bulkManifest = null;
    const refs = [], problems = [];
    for (const f of files) {
      if (/\.csv$/i.test(f.name) && f.size < 1e6) {
        const m = manifestOf(await f.text());
        if (m && m.error) { problems.push(`The manifest ${f.name} cannot be used: ${m.error}.`); continue; }
        if (m) {
          bulkManifest = new Map(m.rows.map((r) => [norm(r.file), r]));
          const chosen = new Set(files.map((x) => norm(x.name)));
          const absent = m.rows.filter((r) => !chosen.has(norm(r.file))).map((r) => r.file);
          if (absent.length) problems.push(`The manifest ${f.name} names ${plural(absent.length, "file")} not chosen: ${absent.join(", ")}.`);
          continue;
        }
      }
      refs.push(f);
    }
    bulkRows = refs.map((f) => ({ file: f, done: false, outcome: null }));
    say("bulk-msg", problems.join(" "), problems.length > 0);
    bulkDraw();
  }

  function bulkDraw() {
    const tb = $("bulk-table").querySelector("tbody");
    tb.replaceChildren();
    $("bulk-table").hidden = !bulkRows.length;
    if (!bulkRows.length) { $("bulk-state").textContent = ""; return; }
    if (!$("study-project").value || bulkRecsOf !== $("study-project").value) {
      $("bulk-table").hidden = true;
      $("bulk-state").textContent = `${plural(bulkRows.length, "file")} chosen: ` + ($("study-project").value
        ? "listing the project's recordings…" : "choose the project above to list its recordings.");
      return;
    }
    let matched = 0;
    bulkRows.forEach((row, i) => {
      const name = row.file.name;
      const m = bulkManifest && bulkManifest.get(norm(name));
      const pick = m ? matchByManifest(m) : matchByName(name);
      row.note = pick.why || "";
      row.outcome = null;
      row.done = false;
      const sel = el("select", { id: `bulk-rec-${i}`, "aria-label": `Recording for ${name}` },
        el("option", { value: "" }, "— choose —"), el("option", { value: SKIP }, "Leave this file out"));
      for (const r of bulkRecs) sel.append(el("option", { value: r.id, title: recText(r) }, recText(r)));
      if (pick.rec) { sel.value = pick.rec.id; matched++; }
      const off = el("input", { id: `bulk-off-${i}`, type: "number", step: "0.001", min: "-3600", max: "3600",
        value: m ? m.offset : "0", "aria-label": `${name} starts at (s into the recording)` });
      row.select = sel; row.offset = off;
      row.state = el("td");
      row.result = el("td", { class: "bulk-result" });
      sel.addEventListener("change", () => { row.done = false; row.outcome = null; row.note = ""; bulkRowState(row); bulkResults(); });
      off.addEventListener("input", () => { row.done = false; row.outcome = null; bulkResults(); });
      const file = el("th", { scope: "row", class: "bulk-file" }, name);
      tb.append(el("tr", {}, file, el("td", {}, sel), el("td", {}, off), row.state, row.result));
      bulkRowState(row);
    });
    const n = bulkRows.length, how = bulkManifest ? "by the manifest or by name" : "by name";
    $("bulk-state").textContent = !bulkRecs.length ? "The project has no recording on the server yet."
      : matched === n ? `${plural(n, "file")}, ${n === 1 ? "its recording" : "each one's recording"} chosen ${how}: check, then press “Attach all”.`
      : `${plural(n, "file")}: ${matched} matched to a recording ${how}, ${n - matched} to choose (“— choose —”); then press “Attach all”.`;
    bulkResults();
  }

  // the chosen recording's reference attached on this page now (its name and steps)
  async function bulkRowState(row) {
    const rid = row.select.value;
    const rec = bulkRecs.find((r) => r.id === rid);
    row.state.textContent = !rec ? "" : rec.has_reference ? "yes" : "none";
    if (!rec || !rec.has_reference) return;
    try {
      const r = await json(`/api/reports/recordings/${encodeURIComponent(rid)}/reference`);
      if (row.select.value !== rid || !r.attached) return;
      row.state.textContent = `${r.filename} (${plural(r.n_steps, "step")})`;
    } catch (e) { /* "yes" stays */ }
  }

  // each row's result: its upload's, else two files for one recording, else why none is chosen
  function bulkResults() {
    const by = new Map();
    for (const row of bulkRows) {
      const v = row.select.value;
      if (v && v !== SKIP) by.set(v, [...(by.get(v) || []), row]);
    }
    let clashes = 0;
    for (const row of bulkRows) {
      const others = (by.get(row.select.value) || []).filter((o) => o !== row);
      let text = "", bad = false;
      if (row.outcome) ({ text, bad } = row.outcome);
      else if (others.length) { text = `Also chosen for ${others.map((o) => o.file.name).join(", ")}: a recording takes one reference.`; bad = true; clashes++; }
      else if (!row.select.value) { text = row.note || "Choose its recording."; }
      row.result.textContent = text;
      row.result.classList.toggle("error", bad);
    }
    return clashes;
  }

  function bulkLock(on) {
    bulkBusy = on;
    for (const row of bulkRows) { row.select.disabled = on; row.offset.disabled = on; }
    $("bulk-files").disabled = on;
    $("study-project").disabled = on;
    if (on) $("bulk-attach").disabled = true; else gaitrig.release($("bulk-attach"));
  }

  async function bulkAttach() {
    if (bulkBusy) return;
    if (!$("study-project").value) { say("bulk-msg", "Choose the project above first.", true); $("study-project").focus(); return; }
    if (!bulkRows.length) { say("bulk-msg", "Choose the reference files first.", true); $("bulk-files").focus(); return; }
    const open = bulkRows.filter((r) => !r.select.value);
    if (open.length) {
      say("bulk-msg", `Choose a recording for ${open.map((r) => r.file.name).join(", ")} (or “Leave this file out”).`, true);
      open[0].select.focus();
      return;
    }
    if (bulkResults()) {
      say("bulk-msg", "Two files are chosen for the same recording: choose another recording for one of them (their rows say which). Nothing was attached.", true);
      const first = bulkRows.find((r) => r.result.classList.contains("error") && !r.outcome);
      if (first) first.select.focus();
      return;
    }
    const todo = bulkRows.filter((r) => r.select.value !== SKIP && !r.done);
    const badOffset = todo.find((r) => r.offset.value === "" || !Number.isFinite(Number(r.offset.value)) || Math.abs(Number(r.offset.value)) > 3600);
    if (badOffset) {
      say("bulk-msg", `The start of ${badOffset.file.name} must be a number of seconds between −3600 and 3600.`, true);
      badOffset.offset.focus();
      return;
    }
    if (!todo.length) { say("bulk-msg", "Every file is attached already (or left out)."); return; }
    bulkLock(true);
    let ok = 0;
    const failed = [];
    say("bulk-msg", `0 of ${todo.length} attached…`);
    for (const row of todo) {
      const rid = row.select.value, name = row.file.name;
      row.outcome = { text: "Attaching…", bad: false };
      bulkResults();
      try {
        const r = await uploadReference(rid, row.file, String(Number(row.offset.value)));
        row.done = true;
        row.outcome = { text: `Attached: ${plural(r.n_steps, "step")}`, bad: false };
        const rec = bulkRecs.find((x) => x.id === rid);
        if (rec) rec.has_reference = true;
        row.state.textContent = `${r.filename} (${plural(r.n_steps, "step")})`;
        ok++;
      } catch (e) {
        // the server's refusal names the file and what to fix; the recording keeps the
        // reference it had
        row.outcome = { text: e.message.includes(name) ? `Not attached: ${e.message}` : `Not attached: ${name}: ${e.message}`, bad: true };
        failed.push(name);
      }
      bulkResults();
      if (ok + failed.length < todo.length) say("bulk-msg", `${ok} of ${todo.length} attached…`);
    }
    bulkLock(false);
    say("bulk-msg", failed.length
      ? `${ok} of ${todo.length} attached; not attached: ${failed.join(", ")} — ${failed.length === 1 ? "its row says" : "their rows say"} why. Press “Attach all” again once fixed: attached files are not sent again.`
      : `${ok} of ${todo.length} attached. “Show agreement” now uses them.`, failed.length > 0);
    if ($("recording").value) refreshReference();
  }

  // ------------------------------------------------------------------ file analysis
  async function analyseFile(format) {
    const f = $("file").files[0];
    if (!f) { say("file-msg", "Choose a .c3d, .trc or .csv file.", true); return; }
    const code = $("file-subject").value.trim() || "upload";
    const fd = new FormData();
    fd.append("file", f);
    // the code goes in the form: a URL is kept in access logs and browser history
    fd.append("subject", code);
    const q = new URLSearchParams({ format, method: $("file-method").value });
    // "Options for files from other labs": only what differs from automatic is sent; a
    // refusal names these fields (advice=form), not gaitrig gait's flags
    const opts = { up: $("file-up").value, units: $("file-units").value,
      left: $("file-left").value.trim(), right: $("file-right").value.trim(),
      ankle_markers: $("file-ankle").value === "auto" ? "" : $("file-ankle").value,
      ankle_width_mm: $("file-width").value.replace(/\s+/g, "") };
    for (const [k, v] of Object.entries(opts)) if (v) q.set(k, v);
    q.set("advice", "form");
    if (format === "pdf") {
      // multipart POST: fetch, then hand the blob to the browser
      say("file-msg", `Analysing ${f.name}…`);
      try {
        const r = await call(`/api/reports/upload?${q}`, { method: "POST", body: fd });
        const blob = await r.blob();
        const a = el("a", { href: URL.createObjectURL(blob), download: `gait-report-${code}.pdf` });
        document.body.append(a); a.click(); a.remove();
        say("file-msg", "PDF downloaded.");
      } catch (e) { say("file-msg", e.message, true); }
      return;
    }
    say("file-msg", `Analysing ${f.name}…`);
    try {
      const r = await call(`/api/reports/upload?${q}`, { method: "POST", body: fd });
      showReport(await r.text());
      say("file-msg", "Report below.");
    } catch (e) { hideReport(); say("file-msg", e.message, true); }
  }

  // ------------------------------------------------------------------ wiring
  $("subject").addEventListener("change", subjectChanged);
  for (const id of ["session", "method", "estimator"]) {
    $(id).addEventListener("change", () => { setLink($("pdf"), subjectQuery("pdf")); updateRecLinks(); });
  }
  $("subject-form").addEventListener("submit", showSubject);
  $("pdf").addEventListener("click", (ev) => {
    ev.preventDefault();
    const url = subjectQuery("pdf");
    // (a keyboard user's Enter on the greyed link did nothing visible)
    if (url) downloadPdf(url, "subject-msg", "gait-report.pdf");
    else say("subject-msg", "Choose a subject first.", true);
  });
  $("rec-pdf").addEventListener("click", (ev) => {
    ev.preventDefault();
    const url = recQuery("pdf");
    if (url) downloadPdf(url, "cmp-msg", "gait-report.pdf");
    else say("cmp-msg", "Choose a recording and at least one sensor in subset A.", true);
  });
  $("study-form").addEventListener("submit", showStudy);
  $("study-project").addEventListener("change", showWhole);
  $("study-project").addEventListener("change", bulkLoadRecordings);
  $("bulk-files").addEventListener("change", bulkFilesChosen);
  $("bulk-attach").addEventListener("click", bulkAttach);
  $("study-pdf").addEventListener("click", () => {
    const url = studyQuery("pdf");
    if (url) downloadPdf(url, "study-msg", "agreement.pdf");
  });
  $("study-csv").addEventListener("click", () => {
    const url = studyQuery("csv");
    if (url) downloadPdf(url, "study-msg", "agreement.csv", "CSV");
  });
  $("recording").addEventListener("change", recordingChanged);
  onSearch($("subject-q"), loadSubjects);
  onSearch($("recording-q"), loadRecordings);
  $("compare").addEventListener("click", compare);
  $("rec-report").addEventListener("click", recReport);
  $("ref-form").addEventListener("submit", attachReference);
  $("ref-remove").addEventListener("click", removeReference);
  $("file-form").addEventListener("submit", (ev) => { ev.preventDefault(); analyseFile("html"); });
  $("file-pdf").addEventListener("click", () => analyseFile("pdf"));
  // The Subjects page links here with #subject=ID[&session=ID]: that report is chosen and
  // shown at once (the choice is kept in the address, so a reload shows it again).
  function keepChoice() {
    const q = new URLSearchParams();
    if ($("subject").value) q.set("subject", $("subject").value);
    if ($("subject").value && $("session").value) q.set("session", $("session").value);
    history.replaceState(null, "", q.toString() ? `#${q}` : location.pathname);
  }
  $("subject").addEventListener("change", keepChoice);
  $("session").addEventListener("change", keepChoice);
  $("session").addEventListener("change", showSessionPick);
  $("session").addEventListener("change", showWhole);
  async function fromAddress() {
    const q = new URLSearchParams(location.hash.slice(1));
    const sid = q.get("subject");
    if (!sid) return;
    if (!subjects.some((s) => String(s.id) === sid)) {
      say("subject-msg", "The subject of this link is not on the server any more: choose one above.", true);
      return;
    }
    $("subject").value = sid;
    await subjectChanged();
    const sess = q.get("session");
    if (sess && [...$("session").options].some((o) => o.value === sess)) { $("session").value = sess; showWhole(); }
    setLink($("pdf"), subjectQuery("pdf"));
    $("subject-form").requestSubmit();
  }
  loadSubjects().then(fromAddress);
  buildSubset("set-a", []); buildSubset("set-b", []);
  loadRecordings();
  loadProjects().then(bulkLoadRecordings);
})();
