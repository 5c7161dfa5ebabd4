// Subjects & recordings page: projects, subjects (CRUD), sessions, recordings with their
// states, reasons and transfer progress, disk usage, exports, reference upload, deletion
// with the subject code typed again. Plain JS; data from /api/{projects,subjects,
// sessions,storage,exports}.
"use strict";
(() => {
  const api = gaitrig.api;
  const $ = (id) => document.getElementById(id);
  const el = gaitrig.el;
  const bytes = (n) => n >= 2 ** 30 ? (n / 2 ** 30).toFixed(2) + " GB" : n >= 2 ** 20 ? (n / 2 ** 20).toFixed(1) + " MB" : (n / 1024).toFixed(0) + " kB";
  const cm = (m) => m === null || m === undefined ? "" : (m * 100).toFixed(1);
  const num = (v) => v === "" || v === null || v === undefined ? null : Number(v);
  function say(id, text, good = false) { const m = $(id); m.textContent = text; m.className = "msg " + (good ? "good" : "bad"); }
  const STATE_TEXT = { recording: "recording", on_nodes: "on the nodes", transferring: "transferring",
    complete: "complete", incomplete: "incomplete", on_node: "on the node", pending: "starting" };
  const badge = (s) => el("span", { class: "badge st-" + s }, STATE_TEXT[s] || s);

  let projectId = null, subjectId = null, subject = null, timer = null;

  function subjectBody(form) {
    const f = form.elements;
    return { code: f.code.value.trim(), sex: f.sex.value, birth_year: num(f.birth_year.value),
      height_m: num(f.height_cm.value) === null ? null : num(f.height_cm.value) / 100,
      leg_length_m: num(f.leg_cm.value) === null ? null : num(f.leg_cm.value) / 100,
      notes: f.notes.value };
  }

  const listPage = gaitrig.listPage;

  async function loadDisk() {
    try {
      // (the disk only: the bytes of every subject read every recording folder)
      const u = await api("/api/storage?subjects=false");
      $("disk").textContent = `Server disk: ${bytes(u.disk.free)} free of ${bytes(u.disk.total)}.`;
    } catch (e) { $("disk").textContent = "Disk usage unavailable: " + e.message; }
  }

  // "Knee OA (0)" said nothing of what was counted, and stayed 0 after a subject was added
  const projectText = (p) => `${p.name} (${gaitrig.plural(p.n_subjects, "subject")})`;
  async function projectCounts() {
    let ps = [];
    try { ps = await api("/api/projects"); } catch (e) { return; }  // (the counts only)
    const byId = new Map(ps.map((p) => [String(p.id), p]));
    for (const o of $("project").options) if (byId.has(o.value)) o.textContent = projectText(byId.get(o.value));
  }
  async function loadProjects(select) {
    const ps = await api("/api/projects");
    const sel = $("project");
    sel.replaceChildren(...ps.map((p) => el("option", { value: p.id, "data-name": p.name }, projectText(p))));
    if (!ps.length) { sel.append(el("option", { value: "" }, "— create a project first —")); projectId = null; }
    else {
      projectId = select ?? (ps.some((p) => p.id === projectId) ? projectId : ps[0].id);
      sel.value = projectId;
    }
    await loadSubjects();
  }

  // Lists overlap (a click on a subject, a deletion, a project change): a list asked
  // before a newer one is dropped, else it could bring back a subject just deleted.
  // A clinic has thousands of subjects: the list shows a page of them, searched and
  // ordered by the server.
  const PAGE = 50;
  let offset = 0;
  const subjectsSeq = gaitrig.latest();
  async function loadSubjects() {
    const mine = subjectsSeq.ask();
    const body = $("subjects");
    if (projectId === null) { body.replaceChildren(); $("subjects-count").textContent = ""; return; }
    const q = $("subject-q").value.trim(), sort = $("subject-sort").value;
    const { items: ss, total } = q
      ? await listPage("/api/subjects/search", { q, project_id: projectId, sort, limit: PAGE, offset })
      : await listPage(`/api/subjects?project_id=${projectId}&sort=${encodeURIComponent(sort)}&limit=${PAGE}&offset=${offset}`);
    if (!subjectsSeq.current(mine)) return;
    if (!ss.length && offset > 0 && total > 0) { offset = Math.max(0, Math.floor((total - 1) / PAGE) * PAGE); return loadSubjects(); }
    $("subjects-count").textContent = total
      ? `Subjects ${offset + 1}–${offset + ss.length} of ${total}${q ? ` with “${q}” in the code` : ""}.`
      : (q ? `No subject code contains “${q}” in this project.` : "");
    $("subjects-prev").disabled = offset === 0;
    $("subjects-next").disabled = offset + ss.length >= total;
    body.replaceChildren(...ss.map((s) => {
      const tr = el("tr", { class: "clickable" + (s.id === subjectId ? " selected" : ""), "data-subject": s.code },
        el("th", { scope: "row", class: "code-cell" }, el("a", { href: `#subject=${s.id}`, title: s.code, onclick: (ev) => { ev.preventDefault(); select(s.id, true); } }, s.code)),
        el("td", { class: "num" }, String(s.n_sessions)), el("td", { class: "num" }, String(s.n_recordings)),
        el("td", { class: "num" }, bytes(s.bytes_on_server)));
      tr.addEventListener("click", () => select(s.id, true));
      return tr;
    }));
    if (!ss.length && !q) body.append(el("tr", {}, el("td", { colspan: "4", class: "hint" }, "No subjects in this project yet.")));
    if (q && !total) await elsewhere(q, mine);
  }
  // A code searched for in another project than the one shown: say where, with a way there.
  async function elsewhere(q, mine) {
    let found = [];
    try { found = (await listPage("/api/subjects/search", { q, limit: 5, bytes_on_server: false })).items; } catch (e) { return; }
    if (!subjectsSeq.current(mine) || !found.length) return;
    const names = new Map([...$("project").options].map((o) => [Number(o.value), o.dataset.name || o.textContent]));
    $("subjects").append(...found.map((s) => el("tr", { "data-elsewhere": s.code }, el("td", { colspan: "4", class: "hint" },
      `${s.code} is in project ${names.get(s.project_id) || s.project_id}: `,
      el("a", { href: `#subject=${s.id}`, onclick: async (ev) => {
        ev.preventDefault(); $("subject-q").value = ""; offset = 0; await loadProjects(s.project_id); await select(s.id);
      } }, `open ${s.code}`)))));
  }
  function turnPage(by) { offset = Math.max(0, offset + by); loadSubjects().catch((e) => say("subject-msg", e.message)); }
  let typing = null;
  function searchNow() { clearTimeout(typing); offset = 0; loadSubjects().catch((e) => say("subject-msg", e.message)); }
  $("subject-q").addEventListener("input", () => { clearTimeout(typing); typing = setTimeout(searchNow, 250); });
  $("subject-search").addEventListener("submit", (ev) => { ev.preventDefault(); searchNow(); });
  $("subject-sort").addEventListener("change", searchNow);
  $("subjects-prev").addEventListener("click", () => turnPage(-PAGE));
  $("subjects-next").addEventListener("click", () => turnPage(PAGE));

  // reveal: a click in the list. On a tablet the details are under the list, out of
  // sight: the click seemed to do nothing, so the page goes to them.
  async function select(id, reveal = false) {
    if (id !== subjectId) { refNotes.clear(); refInputs.clear(); }  // (another subject's uploads are not this one's)
    subjectId = id;
    revealWanted = revealWanted || reveal;
    history.replaceState(null, "", `#subject=${id}`);
    await loadSubjects();
    await loadDetail(true);
  }

  // `lp`: the server's live part (GET /api/recordings), which keeps the reason of a part
  // that ended complete (a node that reconnected and kept recording, a part recovered after
  // a crash) and counts the frames recorded without their images. A reason is an error
  // only while the part is incomplete; a failed transfer is no news once it is complete.
  function partLine(recId, p, lp) {
    const line = el("div", { class: "part", "data-node": p.node_id },
      el("strong", {}, p.node_id), badge(p.state),
      el("progress", { max: "1", value: String(p.progress), "aria-label": `transfer of ${p.node_id}` }),
      el("span", { class: "num" }, `${Math.round(p.progress * 100)} % of ${bytes(p.bytes_total)}, ${gaitrig.plural(p.n_frames, "frame")}`));
    let reason = p.reason || (lp && lp.reason) || "";
    if (p.state !== "incomplete") reason = reason.split("; transfer failed")[0].replace(/^transfer failed.*/, "");
    if (reason) line.append(el("span", { class: p.state === "incomplete" ? "reason" : "note", "data-kind": "reason" }, reason));
    const skipped = p.images_skipped ?? (lp ? lp.images_skipped : null);
    if (skipped > 0)
      line.append(el("span", { class: "note", "data-kind": "images-skipped" },
        `${skipped} frame${skipped === 1 ? "" : "s"} without ${skipped === 1 ? "its" : "their"} images (the sensor's image encoder fell behind)`));
    return line;
  }

  // A recording's export that the server refuses (a part not on the server, too many
  // images…) was a failed download in the browser's download bar, without the reason:
  // these go through fetch, and what happens is said beside the link: preparing, done
  // (file and size) or the refusal. The subject's zip said nothing at all while it was
  // put together (minutes with many recordings). `data-what` names the download in the
  // messages, `data-note` adds to "Preparing…". A second press while one runs is ignored.
  // (The browser keeps a large answer's blob on disk, not in the page's memory.)
  async function download(ev) {
    ev.preventDefault();
    const a = ev.currentTarget, msg = a.parentNode.querySelector(".msg");
    if (a.getAttribute("aria-disabled") === "true") return;
    const what = a.dataset.what || a.textContent;
    const tell = (text, good) => { msg.textContent = text; msg.className = "msg " + (good ? "good" : "bad"); };
    const What = what.charAt(0).toUpperCase() + what.slice(1);
    tell(`Preparing ${what}…${a.dataset.note ? " " + a.dataset.note : ""}`, true);
    a.setAttribute("aria-disabled", "true");
    try {
      const r = await fetch(a.href, { credentials: "same-origin" });
      if (r.status === 401) { gaitrig.toLogin(); return; }
      if (!r.ok) {
        let d = r.statusText; try { d = (await r.json()).detail || d; } catch (e) { /* not JSON */ }
        tell(`${What} not exported: ${d}`); return;
      }
      const m = /filename="([^"]+)"/.exec(r.headers.get("Content-Disposition") || "");
      const name = m ? m[1] : "";
      const blob = await r.blob();
      const url = URL.createObjectURL(blob);
      const tmp = el("a", { href: url, download: name });
      document.body.append(tmp); tmp.click(); tmp.remove();
      setTimeout(() => URL.revokeObjectURL(url), 10000);
      tell(`${What} downloaded (${name ? name + ", " : ""}${bytes(blob.size)}).`, true);
    } catch (e) {
      // (a stream cut short ends here too: "network error")
      tell(`${What} not exported: ${e.message === "Failed to fetch" || e.name === "TypeError"
        ? "the connection to the server broke off; try again" : e.message}`);
    } finally { a.removeAttribute("aria-disabled"); }
  }
  $("export-link").addEventListener("click", download);

  function exportLinks(r) {
    const box = keep(`rec:${r.id}:exports`, "", () => el("div", { class: "actions" }, el("span", { class: "hint" }, "Export:")));
    const msg = keep(`rec:${r.id}:export-msg`, "", () => el("span", { class: "msg", role: "status" }));
    const complete = r.parts.filter((p) => p.state === "complete");
    const links = keep(`rec:${r.id}:export-links`, JSON.stringify([complete.map((p) => p.node_id), r.streams]), () => {
      const link = (href, text) => el("a", { class: "button", href, download: "", onclick: download }, text);
      const out = ["c3d", "trc", "csv"].map((f) => link(`/api/exports/${r.id}/skeleton?format=${f}&source=fused`, `fused ${f.toUpperCase()}`));
      for (const p of complete) {
        out.push(link(`/api/exports/${r.id}/skeleton?format=csv&source=${encodeURIComponent(p.node_id)}`, `${p.node_id} CSV`));
        if (r.streams.includes("depth"))
          out.push(link(`/api/exports/${r.id}/depth?node=${encodeURIComponent(p.node_id)}&format=zip`, `${p.node_id} depth PNG`));
      }
      return out;
    });
    patch(box, [box.firstChild, links, msg]);
    return box;
  }

  // What happened to each recording's reference upload, by recording id: the list is
  // drawn again after an attach (and every second while a recording is busy), which wiped
  // "Attached." at once and lost "Uploading…" and the disabled button with it.
  const refNotes = new Map();  // rec_id → { text, kind: "good" | "bad" | "" }
  const refBusy = new Set();   // rec_ids whose upload is on its way
  const refInputs = new Map(); // rec_id → its file input

  const refButton = (recId) => document.querySelector(`[data-reference-box="${CSS.escape(recId)}"] button`);

  // Which reference a report uses (app/api/routes/reports.py, _reference_paths): one
  // attached on the Reports page comes first; else the newest attached here.
  const refUsed = (n) => `Reports use ${n === 1 ? "this reference" : "the newest of these (the last)"}, unless one is attached to this recording on the Reports page.`;

  function referenceBox(r) {
    const box = keep(`rec:${r.id}:refs`, "", () => el("div", { class: "actions", "data-reference-box": r.id }));
    const listed = keep(`rec:${r.id}:ref-links`, JSON.stringify(r.references), () => {
      const out = r.references.map((x) => el("a", { class: "button", href: `/api/exports/${r.id}/references/${x.id}` },
        `reference ${x.filename} (${x.format.toUpperCase()}, ${x.rate_hz.toFixed(0)} Hz, ${gaitrig.plural(x.labels.length, "label")})`));
      if (r.references.length) out.push(el("span", { class: "hint", "data-kind": "reference-used" }, refUsed(r.references.length)));
      return out;
    });
    // the same file input in every drawing: a new one dropped the file chosen in it
    let input = refInputs.get(r.id);
    if (!input) {
      input = el("input", { type: "file", accept: ".c3d,.trc,.csv", id: `ref-${r.id}` });
      refInputs.set(r.id, input);
    }
    const up = keep(`rec:${r.id}:ref-button`, "", () => attachButton(r.id, input));
    up.disabled = refBusy.has(r.id);
    const label = keep(`rec:${r.id}:ref-label`, "", () => el("label", { for: `ref-${r.id}`, class: "hint" }, "Reference (Vicon C3D, TRC, CSV):"));
    const msg = keep(`rec:${r.id}:ref-msg`, "", () => {
      const note = refNotes.get(r.id);
      return el("span", { class: "msg" + (note && note.kind ? " " + note.kind : ""), role: "status", id: `ref-msg-${r.id}` },
        note ? note.text : "");
    });
    patch(box, [listed, label, input, up, msg]);
    return box;
  }

  // (one button per recording, kept from drawing to drawing, as its message is)
  function attachButton(recId, input) {
    const r = { id: recId };
    // (written into whichever box shows the recording now)
    const tell = (text, kind) => {
      refNotes.set(r.id, { text, kind });
      const m = document.getElementById(`ref-msg-${r.id}`);
      if (m) { m.textContent = text; m.className = "msg" + (kind ? " " + kind : ""); }
    };
    const up = el("button", { type: "button", class: "secondary small", onclick: async () => {
      if (refBusy.has(r.id)) return;
      if (!input.files.length) { tell("Choose a C3D, TRC or CSV file first.", "bad"); return; }
      const file = input.files[0];
      const fd = new FormData(); fd.append("file", file);
      refBusy.add(r.id); up.disabled = true;
      tell(`Uploading ${file.name}…`, "");
      let attached = false;
      try {
        const res = await fetch(`/api/exports/${r.id}/references`, { method: "POST", body: fd, credentials: "same-origin" });
        if (res.status === 401) { refNotes.delete(r.id); gaitrig.toLogin(); return; }
        if (!res.ok) {
          let d = res.statusText; try { d = (await res.json()).detail || d; } catch (e) { /* not JSON */ }
          // (the server's refusal of the file names it: "'walk.c3d' is not a readable C3D file: …")
          tell(String(d).includes(file.name) ? `Not attached: ${d}` : `${file.name} not attached: ${d}`, "bad"); return;
        }
        tell(`${file.name} attached.`, "good");
        input.value = "";
        attached = true;
      } catch (e) {
        tell(`${file.name} not attached: the connection to the server broke off; try again`, "bad");
      } finally {
        refBusy.delete(r.id);
        up.disabled = false;
        // (the list may have been drawn again meanwhile) the focus, dropped to the page while
        // the button was disabled, goes back to it: the message beside it is said while the
        // focus stays on the button pressed, as on the Reports page
        gaitrig.release(refButton(r.id) || up);
      }
      if (!attached) return;
      await loadDetail(false);  // lists the new reference; the button and its message stay
    } }, "Attach reference");
    return up;
  }

  function recordingRow(r, live) {
    latest.set(r.id, r);
    const k = (part) => `rec:${r.id}:${part}`;
    const box = keep(k("box"), "", () => el("div", { class: "recording", "data-recording": r.id }));
    if (box.dataset.state !== r.state) box.dataset.state = r.state;
    // The recording's name and state: the one part of the list that speaks ("walk 2
    // complete"), when the state changes and only then (its words are set only when they
    // differ; the rest of the list is no live region).
    const title = keep(k("title"), "", () => el("span", { class: "rec-title", role: "status" },
      el("strong"), " ", el("span")));
    setText(title.firstChild, r.label || r.id);
    setText(title.lastChild, STATE_TEXT[r.state] || r.state);
    title.lastChild.className = "badge st-" + r.state;
    // (the console's one way: "Nov 28, 2026, 11:40:27 AM", not a bare "11:40:27 AM")
    const when = r.t_start ? gaitrig.dateTime(r.t_start) : "";
    const dur = r.duration_s !== null ? `${r.duration_s.toFixed(1)} s` : "running";
    const about = `${r.id} · ${when} · ${dur} · ${bytes(r.bytes_on_server || 0)} on the server`;
    const head = keep(k("head"), "", () => el("div", { class: "part" }));
    patch(head, [title, keep(k("about"), about, () => el("span", { class: "hint" }, about))]);
    const lparts = new Map((live ? live.parts : []).map((p) => [p.node_id, p]));
    const rows = [head];
    if (r.reason) rows.push(keep(k("reason"), r.reason, () => el("p", { class: "reason" }, r.reason)));
    for (const p of r.parts) {
      const lp = lparts.get(p.node_id);
      rows.push(keep(k("part:" + p.node_id), JSON.stringify([p, lp || null]), () => partLine(r.id, p, lp)));
    }
    for (const n of (live && live.not_in_recording) || [])
      rows.push(keep(k("left-out:" + n.node_id), n.reason, () =>
        el("p", { class: "note", "data-left-out": n.node_id }, `${n.node_id} is not in this recording: ${n.reason}.`)));
    rows.push(recordingActions(r));
    if (r.state === "complete" || r.parts.some((p) => p.state === "complete")) rows.push(exportLinks(r));
    rows.push(referenceBox(r));
    patch(box, rows);
    return box;
  }

  // Transfer again, and the deletion with the subject code typed: the box, its button and
  // its refusal are kept from drawing to drawing (the code typed, the focus and the
  // refusal were wiped every second while a recording was busy).
  function recordingActions(r) {
    const k = (part) => `rec:${r.id}:${part}`;
    const acts = keep(k("actions"), "", () => el("div", { class: "actions" }));
    const transfer = r.state === "incomplete" || r.state === "on_nodes"
      ? keep(k("transfer"), "", () => el("button", { type: "button", class: "secondary small", onclick: async () => {
        try { await api(`/api/storage/recordings/${r.id}/transfer`, { method: "POST" }); say("session-msg", `Transfer of ${r.id} started.`, true); }
        catch (e) { say("session-msg", e.message); }
        await loadDetail(false);
      } }, "Transfer again")) : null;
    const confirm = keep(k("confirm:" + subject.code), "", () => el("input", { "aria-label": `type ${subject.code} to delete ${r.id}`, placeholder: `type ${subject.code}`, size: "8", autocomplete: "off" }));
    // a refusal is said beside the button pressed: written above the session's list, it was
    // off screen for a recording further down, and the press seemed to do nothing
    const refusal = keep(k("refusal"), "", () => el("span", { class: "msg bad", role: "alert" }));
    const del = keep(k("delete"), "", () => el("button", { type: "button", class: "danger small", onclick: async () => {
      const input = acts.querySelector("input");
      const now = latest.get(r.id) || r;
      refusal.textContent = "";
      if (input.value.trim() !== subject.code) {
        refusal.textContent = `Not deleted: type ${subject.code} in the box first, then press Delete recording.`;
        input.focus(); return;
      }
      try { const d = await api(`/api/storage/recordings/${r.id}/delete`, { method: "POST", body: JSON.stringify({ confirm: input.value }) });
        const left = Object.entries(d.node_copies || {}).filter(([, v]) => v !== "deleted").map(([n, v]) => `${n}: ${v}`);
        say("session-msg", `Recording ${now.label ? now.label + " (" + r.id + ")" : r.id} deleted on the server and the nodes.` + (left.length ? ` Not yet on ${left.join("; ")}.` : ""), true);
        $("session-msg").scrollIntoView({ block: "nearest" });  // (the row pressed is gone)
        await loadDetail(false); await loadSubjects(); }
      catch (e) { refusal.textContent = `Not deleted: ${e.message}`; }
    } }, "Delete recording"));
    patch(acts, [transfer, confirm, del, refusal]);
    return acts;
  }

  // An unfiled recording is health data all the same: deleting it needs its id typed.
  function unfiledDelete(r) {
    const input = el("input", { "aria-label": `type ${r.id} to delete it`, placeholder: "recording id", autocomplete: "off", size: "22" });
    return el("details", { class: "danger-zone" }, el("summary", {}, "Delete…"),
      el("span", { class: "form-row" }, input, el("button", { type: "button", class: "danger small", onclick: async () => {
        try { const d = await api(`/api/storage/unfiled/${encodeURIComponent(r.id)}/delete`, { method: "POST", body: JSON.stringify({ confirm: input.value.trim() }) });
          const left = Object.entries(d.node_copies).filter(([, v]) => v !== "deleted").map(([n, v]) => `${n}: ${v}`);
          say("session-msg", `Recording ${r.id} deleted${left.length ? " (" + left.join("; ") + ")" : ", on the nodes too"}.`, true); await loadDetail(false); }
        catch (e) { say("session-msg", e.message); }
      } }, "Delete recording")));
  }

  // Recordings started without a session (e.g. from the Rig page) can be filed here; the
  // card of those in `recs`, or null.
  function unfiledCard(recs) {
    if (!recs.length || !subject.sessions.length) return null;
    const sig = JSON.stringify([recs, subject.code, subject.sessions.map((x) => [x.id, x.date, x.label])]);
    return keep("unfiled", sig, () => {
      const card = el("div", { class: "session", id: "unfiled" }, el("h3", {}, "Recordings not filed under a session"));
      for (const r of recs) {
        const sel = el("select", { "aria-label": `session for ${r.id}` },
          ...subject.sessions.slice().reverse().map((x) => el("option", { value: x.id }, `${gaitrig.day(x.date)}${x.label ? " — " + x.label : ""}`)));
        card.append(el("div", { class: "part", "data-unfiled": r.id },
          el("strong", {}, r.id), badge(r.state), el("span", { class: "hint" }, r.nodes.join(", ")), sel,
          el("button", { type: "button", class: "secondary small", onclick: async () => {
            try { await api(`/api/sessions/${sel.value}/recordings/attach`, { method: "POST", body: JSON.stringify({ rec_id: r.id }) });
              say("session-msg", `Recording ${r.id} filed under ${subject.code}.`, true); await loadDetail(false); await loadSubjects(); }
            catch (e) { say("session-msg", e.message); }
          } }, `File under ${subject.code}`),
          unfiledDelete(r)));
      }
      return card;
    });
  }

  // The list of sessions and recordings is drawn again every second while a recording is
  // busy. It was one live region, replaced whole at each drawing: a screen reader could
  // read all of it out again every second, delete boxes and all. Now only each
  // recording's title (name and state badge) and the messages beside its buttons are live
  // regions, and a drawing keeps every element whose content has not changed where it is:
  // a live region taken out and put back may be read out again (an alert is), and the
  // focus, a code typed into a delete box or a refusal beside a button went with it.
  // `keep` gives the element drawn last under `key` while its `sig` (its content) is the
  // same, `patch` puts elements into a parent without moving those already in place.
  let kept = new Map(), keptFor = null;  // key → { sig, node }, of the subject keptFor
  const latest = new Map();      // rec_id → its latest entry (for the kept buttons' words)
  function keep(key, sig, make) {
    const k = kept.get(key);
    if (k && k.sig === sig) return k.node;
    const node = make();
    kept.set(key, { sig, node });
    return node;
  }
  function patch(parent, nodes) {
    const want = nodes.flat().filter((n) => n !== null && n !== undefined);
    const keepSet = new Set(want);
    for (const c of [...parent.childNodes]) if (!keepSet.has(c)) c.remove();
    let at = parent.firstChild;
    for (const n of want) {
      if (n === at) at = at.nextSibling;
      else parent.insertBefore(n, at);
    }
  }
  const setText = (node, text) => { if (node.textContent !== text) node.textContent = text; };

  // Each loadDetail() makes the ones still waiting for an answer stale: the subject was
  // deleted or another one chosen meanwhile, or a newer answer is on its way. The edit
  // form is filled by whichever call draws, if any call asked for it.
  const detailSeq = gaitrig.latest();
  let fillWanted = false, revealWanted = false;
  let formVersion = null;
  function dropDetail() { detailSeq.acted(); clearTimeout(timer); }
  async function loadDetail(fillForm) {
    if (subjectId === null) return;
    const gen = detailSeq.ask();
    fillWanted = fillWanted || fillForm;
    let got;
    try { got = await api(`/api/subjects/${subjectId}`); }
    catch (e) {
      if (!detailSeq.current(gen)) return;
      $("detail-h").textContent = "Select a subject"; $("detail-body").hidden = true; subjectId = null; return;
    }
    if (!detailSeq.current(gen)) return;
    subject = got;
    fillForm = fillWanted; fillWanted = false;
    $("detail-h").textContent = `Subject ${subject.code}`;
    $("detail-hint").textContent = `${gaitrig.plural(subject.n_sessions, "session")}, ${gaitrig.plural(subject.n_recordings, "recording")}, ${bytes(subject.bytes_on_server)} on the server.`;
    $("detail-body").hidden = false;
    // (whichever call draws the details goes to them, as soon as they show)
    if (revealWanted && $("detail").getBoundingClientRect().top > window.innerHeight * 0.6) {
      $("detail").scrollIntoView({ block: "start" });
      $("detail-h").focus({ preventScroll: true });
    }
    revealWanted = false;
    $("record-link").href = `/record.html#subject=${subject.id}`;
    // (the recordings were listed here but the way to their gait report was not)
    $("report-link").href = `/reports.html#subject=${subject.id}`;
    // (another subject's download message is not this one's)
    if ($("export-link").getAttribute("href") !== `/api/subjects/${subject.id}/export`) $("export-msg").textContent = "";
    $("export-link").href = `/api/subjects/${subject.id}/export`;
    $("export-link").dataset.what = `all data of ${subject.code} (zip)`;
    if (fillForm) {
      const f = $("edit-form").elements;
      f.code.value = subject.code; f.sex.value = subject.sex; f.birth_year.value = subject.birth_year ?? "";
      f.height_cm.value = cm(subject.height_m); f.leg_cm.value = cm(subject.leg_length_m); f.notes.value = subject.notes;
      formVersion = subject.version;  // a save based on this copy is refused if someone saved since
      // today on the user's calendar (toISOString's UTC date was yesterday or tomorrow
      // for part of the day away from Greenwich)
      const d = new Date();
      $("session-form").elements.date.value = `${d.getFullYear()}-${String(d.getMonth() + 1).padStart(2, "0")}-${String(d.getDate()).padStart(2, "0")}`;
    }
    // the server's live entries of these recordings: what the filed rows do not keep
    const ids = subject.sessions.flatMap((s) => s.recordings.map((r) => r.id));
    let lives = [];
    if (ids.length) {
      try { lives = await api(`/api/recordings?ids=${encodeURIComponent(ids.join(","))}`); } catch (e) { /* the notes are optional */ }
      if (!detailSeq.current(gen)) return;
    }
    const live = new Map(lives.map((x) => [x.id, x]));
    let unfiled = [];
    try { unfiled = await api("/api/storage/unfiled"); } catch (e) { /* the card is optional */ }
    if (!detailSeq.current(gen)) return;
    if (keptFor !== subject.id) { kept = new Map(); latest.clear(); keptFor = subject.id; }
    patch($("sessions"), [
      ...subject.sessions.slice().reverse().map((s) => {
        const card = keep(`session:${s.id}`, "", () => el("div", { class: "session", "data-session": s.id }));
        const done = s.recordings.some((r) => r.state === "complete");
        const h = keep(`session:${s.id}:h`, JSON.stringify([s.date, s.label, done]), () =>
          el("h3", {}, `${gaitrig.day(s.date)}${s.label ? " — " + s.label : ""}`,
            done ? el("a", { class: "button session-report", href: `/reports.html#subject=${subject.id}&session=${s.id}` }, "Gait report of this session") : null));
        patch(card, [h, s.recordings.length ? s.recordings.map((r) => recordingRow(r, live.get(r.id)))
          : keep(`session:${s.id}:none`, "", () => el("p", { class: "hint" }, "No recordings yet."))]);
        return card;
      }),
      subject.sessions.length ? null : keep("no-sessions", "", () => el("p", { class: "hint" }, "No sessions yet: add one above, then record it.")),
      unfiledCard(unfiled)]);
    const busy = subject.sessions.some((s) => s.recordings.some((r) => ["recording", "on_nodes", "transferring"].includes(r.state)));
    clearTimeout(timer);
    // (gaitrig.wait: not while the page is hidden; at once when it is shown again)
    if (busy) timer = setTimeout(() => gaitrig.wait(0).then(() => loadDetail(false)), 1000);
  }

  $("project").addEventListener("change", async (ev) => { projectId = Number(ev.target.value); subjectId = null; offset = 0; dropDetail(); $("detail-body").hidden = true; await loadSubjects(); });
  $("project-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    try { const p = await api("/api/projects", { method: "POST", body: JSON.stringify({ name: ev.target.elements.name.value.trim() }) });
      ev.target.reset(); say("project-msg", `Project ${p.name} created.`, true); await loadProjects(p.id); }
    catch (e) { say("project-msg", e.message); }
  });
  $("subject-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    if (projectId === null) { say("subject-msg", "Create a project first."); return; }
    try { const s = await api("/api/subjects", { method: "POST", body: JSON.stringify({ project_id: projectId, ...subjectBody(ev.target) }) });
      ev.target.reset(); say("subject-msg", `Subject ${s.code} added.`, true); await select(s.id); await projectCounts(); }
    catch (e) { say("subject-msg", e.message); }
  });
  $("edit-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    try { await api(`/api/subjects/${subjectId}`, { method: "PATCH", body: JSON.stringify({ ...subjectBody(ev.target), version: formVersion }) });
      say("edit-msg", "Saved.", true); await loadSubjects(); await loadDetail(true); }
    catch (e) { say("edit-msg", e.message); }
  });
  $("session-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    const f = ev.target.elements;
    try { await api("/api/sessions", { method: "POST", body: JSON.stringify({ subject_id: subjectId, date: f.date.value, label: f.label.value }) });
      f.label.value = ""; say("session-msg", "Session added.", true); await loadDetail(false); await loadSubjects(); }
    catch (e) { say("session-msg", e.message); }
  });
  $("delete-form").addEventListener("submit", async (ev) => {
    ev.preventDefault();
    try { const r = await api(`/api/subjects/${subjectId}/delete`, { method: "POST", body: JSON.stringify({ confirm: ev.target.elements.confirm.value }) });
      ev.target.reset(); subjectId = null; dropDetail(); $("detail-body").hidden = true; $("detail-h").textContent = "Select a subject";
      const left = Object.entries(r.node_copies || {}).filter(([, v]) => v !== "deleted").map(([n, v]) => `${n}: ${v}`);
      say("delete-msg", `Subject deleted with ${gaitrig.plural(r.recordings_deleted, "recording")}${r.recordings_deleted ? (left.length ? "; copies still on nodes — " + left.join("; ") : ", on the nodes too") : ""}.`, true); await loadProjects(); await loadDisk(); }
    catch (e) { say("delete-msg", e.message); }
  });

  (async () => {
    loadDisk();  // not waited for: the subjects are what the user came for
    try { $("audit").hidden = !(await api("/api/auth/me")).is_admin; } catch (e) { /* stays hidden */ }
    const m = /subject=(\d+)/.exec(location.hash);
    if (m) {
      try { const s = await api(`/api/subjects/${m[1]}`); await loadProjects(s.project_id); await select(s.id); return; }
      catch (e) { /* unknown subject: show the list */ }
    }
    await loadProjects();
  })();
})();
